"""The ballbar circular test (ISO 230-4): programs and campaigns, trace formats, the
time-to-angle mapping (``timing``), the error model of a circle (``model``), the fit
(``analysis``, ``joint`` for a campaign), its checks and metrics."""
