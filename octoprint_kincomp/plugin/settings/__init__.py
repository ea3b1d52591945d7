"""Settings on OctoPrint: the stored settings (``settings_store``), their endpoints
(``settings_api``) and the motion limits read from the printer (``limits_capture``)."""
