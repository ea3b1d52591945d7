"""Settings: the schema every way in is checked against (``schema``), per printer profile
(``printer_profiles``), and the software update check (``software_update``)."""
