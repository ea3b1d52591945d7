"""Developer tools: the benchmark and the local OctoPrint server (demo and end-to-end tests)."""
