"""pardem: parallel discrete element method for bonded and granular media."""

__version__ = "0.1.0"
