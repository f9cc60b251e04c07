"""Drivers: thin command-line programs that compose pardem's pieces (``python -m pardem.drivers.X``)."""
