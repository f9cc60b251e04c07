"""The I/O layer: every file pardem writes or reads goes through here."""
