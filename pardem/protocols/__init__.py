"""Test protocols: each builds its case from a deck, adds its operations and measures its results."""
