"""Stop requests: a signal handler records the signal here; ``Simulation.check_stability`` reduces
it over ranks so that every rank stops at the same step boundary (``errors.Interrupted``).

A leaf of plain Python state: installing the handlers is the drivers' business
(``pardem.drivers.cli.stop_signals``); the time loop only reads ``requested()``.
"""
import time

_signum = 0
_since = 0.0


def request(signum):
    """Record that signal ``signum`` asked this process to stop (safe in a signal handler)."""
    global _signum, _since
    if not _signum:
        _signum, _since = int(signum), time.monotonic()


def requested():
    """The signal number of the first stop request on this process, 0 if none."""
    return _signum


def seconds_since():
    """Seconds since the first stop request (``time.monotonic``), 0 if none."""
    return time.monotonic() - _since if _signum else 0.0


def clear():
    global _signum, _since
    _signum, _since = 0, 0.0
