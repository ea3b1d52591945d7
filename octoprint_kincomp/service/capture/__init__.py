"""Live capture: a finished capture stored and analysed as a run (``capture_recorder``)."""
