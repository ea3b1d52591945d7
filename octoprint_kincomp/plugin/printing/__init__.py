"""Printing on OctoPrint: the connection and the print on it (``print_state``)."""
