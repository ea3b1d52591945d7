"""KinComp's server side without OctoPrint: the queue's compensator, the stores, the jobs and
their worker process, the settings schema. Every module here imports neither OctoPrint nor
Flask (``tests/release/test_floors.py`` checks it), so it runs and is tested without a
server; ``plugin/`` wires it to OctoPrint. One subpackage per page of the manual:
``printing`` (the queue and the printer's own compensation), ``files`` (background jobs),
``calibration`` (runs, campaigns, demo mode), ``capture`` (live captures as runs),
``settings`` (the schema, printer profiles, software update); ``notify`` is shared."""
