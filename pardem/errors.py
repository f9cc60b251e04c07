"""Errors of the engine, a leaf module (imported by every layer, importing nothing of pardem).

Drivers map them to exit codes (``pardem.drivers.cli``): ``InstabilityError`` 3, ``OutputError``
4, ``Interrupted`` 128 + signal number, the others 1.
"""


class InjectedFault(RuntimeError):
    """Raised on purpose by ``FaultInjection`` (tests of failure handling)."""


class InstabilityError(RuntimeError):
    """The motion blew up (NaN, runaway speed, overstretched bond): the run must stop."""


class DecompositionError(RuntimeError):
    """The decomposition cannot hold this domain (e.g. slabs thinner than the ghost range)."""


class Interrupted(RuntimeError):
    """A stop signal (SIGTERM, SIGINT) reached some rank; raised on every rank at the same step."""

    def __init__(self, signum, step):
        super().__init__(f"stopped by signal {int(signum)} at step {int(step)}")
        self.signum, self.step = int(signum), int(step)


class StepLimit(Exception):
    """The run reached its ``--steps`` limit (not an error: the driver checkpoints and stops)."""


class OutputError(RuntimeError):
    """A result file could not be written (disk full, permission denied, bad path)."""
