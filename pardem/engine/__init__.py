"""The engine: state, time loop and operations, contacts, periodic cell, builders of systems."""
