"""Files on OctoPrint: the files endpoints and the upload preprocessor (``files_api``,
``upload``), the jobs endpoints (``job_api``)."""
