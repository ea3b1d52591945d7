"""Ballbar side of KinComp: ISO 230-4 test programs, a printer + ballbar simulator, trace
formats and the analysis that turns a trace into KinComp parameters. Pure Python + numpy."""
