"""The progress reporter's rate and ETA (``pardem.io.progress``), on a controlled clock."""
import io

import pytest

from pardem.io import progress as pg


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@pytest.fixture
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(pg.time, "perf_counter", c)
    return c


def report(p, clock, step, t):
    clock.t = t
    p.report(step)


def test_the_rate_is_that_of_the_steps_since_the_previous_line(clock):
    """A run whose steps get 10 times dearer (a 10,000-grain preparation, then 90,000 copies):
    100 steps/s, then 10 steps/s. The line after the change gives 10 steps/s and the ETA of the
    remaining steps at that rate (a rate over the whole run would give 55 and an ETA 5.5 times
    too short)."""
    out = io.StringIO()
    p = pg.Progress(None, total=2000, seconds=1.0, n_elements=90000, stream=out)
    report(p, clock, 0, 0.0)            # the first call: the mark (it paid the compilation)
    report(p, clock, 1000, 10.0)        # 100 steps/s
    report(p, clock, 1100, 20.0)        # 10 steps/s
    first, second = out.getvalue().splitlines()
    assert "100 steps/s" in first and "ETA 10.0 s" in first
    assert "10 steps/s" in second and "(9.000e+05 element-steps/s)" in second and "ETA 1 min 30 s" in second


def test_lines_are_at_most_every_seconds_and_always_at_the_last_step(clock):
    out = io.StringIO()
    p = pg.Progress(None, total=300, seconds=5.0, stream=out)
    for k, t in enumerate([0.0, 1.0, 2.0, 6.0, 7.0]):
        report(p, clock, 50 * k, t)
    report(p, clock, 300, 7.5)
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and lines[0].startswith("step      150/300") and "/300 (100.0 %)" in lines[1]
    # the last line's rate: 150 steps in 1.5 s since the previous line
    assert "100 steps/s" in lines[1]


def test_start_restarts_the_measure(clock):
    out = io.StringIO()
    p = pg.Progress(None, seconds=0.0, stream=out)
    report(p, clock, 0, 0.0)
    clock.t = 100.0
    p.start(5000)                       # a new stage begins at step 5000, now
    report(p, clock, 5020, 102.0)
    assert "10 steps/s" in out.getvalue()
