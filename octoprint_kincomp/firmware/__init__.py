"""What real firmware does with G-code, as KinComp relies on it: the interpreter of what a
program commands (``interpreter``), the motion planner (``planner``), the motion limits a
printer states (``motion_limits``: M503, Klipper's printer.cfg) and KinComp's parameters as each
firmware's own compensation (``export``). Imports ``core/`` only."""
