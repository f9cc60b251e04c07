"""Errors of the engine, a leaf module (imported by every layer, importing nothing of pardem).

Drivers map them to exit codes (``pardem.drivers.cli``): ``InstabilityError`` 3, the others 1.
"""


class InjectedFault(RuntimeError):
    """Raised on purpose by ``FaultInjection`` (tests of failure handling)."""


class InstabilityError(RuntimeError):
    """The motion blew up (NaN, runaway speed, overstretched bond): the run must stop."""


class DecompositionError(RuntimeError):
    """The decomposition cannot hold this domain (e.g. slabs thinner than the ghost range)."""
