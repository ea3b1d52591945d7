"""Calibration on the server: the run history (``run_store``), campaigns (``campaign_store``,
``campaign_measure``), the known out-of-plane squareness, the findings as shown, demo mode."""
