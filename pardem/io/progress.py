"""Progress lines on rank 0: the one reporter of every driver and protocol.

``Progress`` prints ``step k/N (p %)``, the rate in steps and element-steps per second, the ETA and
the caller's own fields, at most every ``seconds`` (and always for the last step). The rate is
that of the steps since the previous line (the first line: since the first call, never from the
run's start: the first step of a run compiles the Numba kernels, seconds, and would make the
first ETA absurd). A rate over the whole run would lag when the cost of a step changes (the
biaxial and response drivers prepare 10,000 grains, then step 90,000 copies: a cumulative rate
said 187 steps/s where the loading ran 53); ``start(step)`` restarts
the measure at a change of stage.

It is an operation (``trigger = Periodic(1)``: after every step; ``__call__(sim)``) and also a
plain reporter (``report``) for callers that sample themselves; ``say`` prints free text (phase
changes). Nothing here is collective: it reads only what rank 0 holds.
"""
import os
import sys
import time

from pardem.triggers import Periodic


class Progress:
    """Rank-0 progress reporter.

    comm: the run's ``Communicator``; total: the step count at which the run ends (from its start);
    seconds: minimum time between lines (0 prints every call); n_elements: multiplies the rate into
    element-steps per second (optional); describe: ``describe(sim) -> str`` for the operation form;
    quiet: print nothing (not even ``say``); label: prefix of every line.
    """
    trigger = Periodic(1)

    def __init__(self, comm, total=None, seconds=10.0, n_elements=None, describe=None, quiet=False,
                 stream=None, label=""):
        self.root = comm is None or comm.is_root
        self.total = None if total is None else int(total)
        self.seconds = float(seconds)
        self.n_elements = n_elements
        self.describe = describe
        self.quiet = bool(quiet)
        self.stream = stream if stream is not None else sys.stdout
        self.label = label
        self._mark = None          # (step, time) the rate is measured from
        self._last = -float("inf")

    @property
    def active(self):
        return self.root and not self.quiet

    def __call__(self, sim):
        if self.active:
            self.report(sim.step_count, self.describe(sim) if self.describe is not None else "")

    def start(self, step):
        """Measure the rate from ``step`` on, now (call after a warm-up step)."""
        self._mark = (int(step), time.perf_counter())

    def rate(self, step, now=None):
        """Steps per second since the mark, the previous line (None before there is one or before
        any step)."""
        if self._mark is None:
            return None
        now = time.perf_counter() if now is None else now
        done, dt = step - self._mark[0], now - self._mark[1]
        return done / dt if done > 0 and dt > 0 else None

    def report(self, step, text="", force=False):
        """One line for ``step`` if ``seconds`` have passed since the last (or ``force``, or the
        last step); ``text``: the caller's fields."""
        if not self.active:
            return
        now = time.perf_counter()
        if self._mark is None:
            # the first call: only a mark (its step paid the compilation)
            self._mark = (int(step), now)
            self._last = now
            return
        last_step = self.total is not None and step >= self.total
        if not (force or last_step or now - self._last >= self.seconds):
            return
        self._last = now
        self.stream.write(self.line(step, text, now) + "\n")
        self.stream.flush()
        if step > self._mark[0]:
            self._mark = (int(step), now)      # the next line's rate: the steps from here

    def line(self, step, text="", now=None):
        """The progress line of ``step`` (no I/O)."""
        parts = [self.label] if self.label else []
        if self.total:
            parts.append(f"step {step:>8d}/{self.total} ({100.0 * step / self.total:5.1f} %)")
        else:
            parts.append(f"step {step:>8d}")
        if text:
            parts.append(text)
        r = self.rate(step, now)
        if r is None:
            parts.append("rate --")
        else:
            parts.append(f"{r:.4g} steps/s" + (f" ({r * self.n_elements:.3e} element-steps/s)"
                                               if self.n_elements else ""))
            if self.total:
                parts.append(f"ETA {_duration(max(self.total - step, 0) / r)}")
        return "  ".join(parts)

    def say(self, text):
        """Print one free line now (rank 0, unless quiet)."""
        if self.active:
            self.stream.write(text + "\n")
            self.stream.flush()


def _duration(seconds):
    """``12.3 s``, ``4 min 05 s`` or ``2 h 07 min``."""
    s = float(seconds)
    if s < 60.0:
        return f"{s:.1f} s"
    if s < 3600.0:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


def silence_stderr():
    """Point this process's stderr (file descriptor 2) at /dev/null, after flushing it: the line a
    driver printed is out, and what a launcher would add after it (MPICH's "Abort(code) on node")
    is not."""
    sys.stderr.flush()
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 2)
