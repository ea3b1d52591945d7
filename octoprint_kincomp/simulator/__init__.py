"""The simulated printer: the play of its drives (``play``), the printer with servo lag,
its true errors and a virtual ballbar (``printer``), the printed artifact it would make
(``artifact``), demo mode's ballbar (``demo``) and the closed loop of calibrate, apply and
re-test (``closed_loop``). All its output is labelled SIMULATED. Imports the floors below
(``core/``, ``engines/``, ``firmware/``, ``calibration/``)."""
