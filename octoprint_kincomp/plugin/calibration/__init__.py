"""Calibration endpoints: single tests and the history (``calibration_api``), campaigns
(``campaign_api``), the printed artifact (``artifact_api``)."""
