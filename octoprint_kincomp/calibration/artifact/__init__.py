"""The printed artifact: its program and drawing, the fit of caliper readings (``fit``) and
the simple diagonals measurement (``diagonals``)."""
