"""The engines: the compiled kernel of the transform, the contract it keeps (``contract.py``)
and the one file loop (``files.py``), the interface through which the queue, uploads and the
command line reach an engine."""
