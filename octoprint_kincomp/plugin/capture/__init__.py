"""The live ballbar sensor's endpoints: preview, arming, the end of a capture (``sensor_api``)."""
