"""The simulated printer's firmware side: what a G-code program commands
(:mod:`.machine`, a firmware-like interpreter) and the play of its drives (:mod:`.play`).
The planner (``ballbar/motion.py``) and the printer with its virtual ballbar
(``ballbar/simulator.py``) build on them; tests use the interpreter as the oracle of where
a program sends the head."""
