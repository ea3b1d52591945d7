"""The engines: the compiled kernel of the transform, the contract it keeps (``contract.py``)
and the one file loop (``file_loop.py``), the interface through which the queue, uploads and the
command line reach an engine."""
