"""The engines: the accelerated paths of the transform (compiled kernel, vectorised file
engine) and whole-file compensation, the one interface through which the queue, uploads and
the command line reach an engine."""
