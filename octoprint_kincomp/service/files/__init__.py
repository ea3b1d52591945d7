"""Files: background jobs (``jobs``) and the low-priority worker process they run in
(``worker``, started as ``python -m octoprint_kincomp.service.files.worker``)."""
