"""Printing: the compensator as the queuing hook sees it (``queue``), the firmware's own
compensation (``firmware_watch``, ``firmware_check``) and the speed factor held during a test."""
