"""Calibration: turning measurements into parameters. ``ballbar/`` (ISO 230-4 test programs,
campaigns, trace formats, the analysis and its checks) and ``artifact/`` (a printed part
measured with calipers) share the findings (``findings``) and the proposal (``proposal``).
Imports ``core/``, ``engines/`` and ``firmware/``."""
