"""A stop signal leaves the state of its step after that step's operations, so that its
checkpoint continues the run bit for bit whatever the operations change.

``Simulation.run`` reduces the stop requests over ranks every ``check_every`` (50) steps and at
its last step; it raises ``Interrupted`` there once the step's operations have run (and on the
last step the ``at_end`` ones). Before, it raised before them: an operation that changes the state
(FIRE's mixing, a servo, a sampler's row) was lost on the stop's step, and only the drivers that
replayed it (biaxial, response) restarted bit for bit.

Oracle: the uninterrupted run of the same system (an independent computation: any operation left
undone or run twice changes the final bits), compared by gid, exactly.
"""
import os
import signal

import numpy as np
import pytest

import pardem
from pardem.engine import stop
from pardem.errors import Interrupted
from pardem.triggers import At, Never

R, RHO = 1e-3, 2500.0
STEPS = 200


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def _system():
    """27 grains in a periodic box, random speeds: contacts from the first steps."""
    rng = np.random.default_rng(3)
    g = np.arange(3) * 2.1 * R
    pos = np.array([[x, y, z] for x in g for y in g for z in g]) + rng.uniform(-0.02, 0.02, (27, 3)) * R
    v = rng.normal(size=pos.shape) * 0.05
    return pardem.System(pardem.Particles(pos, R, RHO, velocities=v),
                         contacts=pardem.ContactModel("linear", {"kn": 1e4, "kt": 1e4, "friction": 0.5,
                                                                 "restitution": 0.8}),
                         cell=pardem.Cell(lo=[-1.05 * R] * 3, length=[6.3 * R] * 3),
                         integration=pardem.Integration(dt_fraction=0.05))


class Cool:
    """Halves every speed on the steps of ``trigger`` (and with ``at_end`` at the end of a run):
    an operation whose effect is in the state."""

    def __init__(self, trigger, at_end=False):
        self.trigger, self.at_end = trigger, at_end

    def __call__(self, sim):
        n = sim.elements.n_owned
        sim.elements.v[:n] *= 0.5
        sim.elements.w[:n] *= 0.5


class Signal:
    """Records a stop request on step ``step``, as the SIGTERM handler does."""

    def __init__(self, step):
        self.trigger = At(step)

    def __call__(self, sim):
        stop.request(signal.SIGTERM)


def _by_gid(sim):
    e = sim.elements
    n = e.n_owned
    o = np.argsort(e.gid[:n])
    return {k: getattr(e, k)[:n][o].copy() for k in ("gid", "x", "v", "w", "f", "t")}


def _chunks(sim, ops, until, chunk):
    while sim.step_count < until:
        sim.run(min(chunk, until - sim.step_count), ops)


@pytest.mark.parametrize("chunk, signal_step, stopped", [
    (STEPS, 95, 100),    # inside one run: the stop's step (100) is one of Cool's (every 10)
    (40, 75, 80),        # at the end of a run (80): the at_end operation runs before the stop
])
def test_a_stopped_run_restarts_as_the_uninterrupted_run(comm, tmp_path, chunk, signal_step, stopped):
    def ops():
        return [Cool(10), Cool(Never(), at_end=True)]
    whole = pardem.build(comm, _system())
    _chunks(whole, ops(), STEPS, chunk)
    sim = pardem.build(comm, _system())
    stop.clear()
    try:
        with pytest.raises(Interrupted) as err:
            _chunks(sim, ops() + [Signal(signal_step)], STEPS, chunk)
    finally:
        stop.clear()
    assert err.value.step == stopped == sim.step_count
    path = str(tmp_path / "stopped.h5")
    pardem.save(sim, path)       # what the driver's final checkpoint holds
    again = pardem.load(comm, path)
    _chunks(again, ops(), STEPS, chunk)
    a, b = _by_gid(whole), _by_gid(again)
    assert whole.step_count == again.step_count == STEPS
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_a_stop_request_is_honoured_at_the_next_check_after_the_steps_operations(comm):
    """The stop comes at the first check (a multiple of ``check_every``, or the run's last step)
    at or after the request, not before, with the step's operations done once."""
    sim = pardem.build(comm, _system())
    calls = []

    class Count:
        trigger = 1

        def __call__(self, s):
            calls.append(s.step_count)
    stop.clear()
    try:
        with pytest.raises(Interrupted) as err:
            sim.run(STEPS, [Count(), Signal(51)])
    finally:
        stop.clear()
    assert err.value.step == 100 == sim.step_count
    assert calls == list(range(1, 101))


# -- a driver: the compress run's series sampled on the stop's step -------------------------

COMPRESS = ["--quiet", "--set", "domain.box=[0.003,0.003,0.003]", "--set", "output.series_every=10",
            "--set", "checkpoint.every_steps=400", "--steps", "1100"]


def _compress(argv, monkeypatch, signal_step=None):
    """The compress driver in this process (216 elements); ``signal_step``: a stop request
    recorded there, as the SIGTERM handler records it (through the runner's fault-injection slot,
    an operation of every ``sim.run``). Returns the exit code."""
    from pardem.drivers import compress, runner
    monkeypatch.setattr(runner.FaultInjection, "from_environment",
                        classmethod(lambda cls: None if signal_step is None else Signal(signal_step)))
    try:
        return compress.main(argv)
    except SystemExit as exc:
        return exc.code


def test_a_stopped_compress_run_restarts_with_the_uninterrupted_series(tmp_path, monkeypatch):
    """Stopped at step 1000 (requested at 975, reduced at the check of step 1000, a sampling
    step): the final checkpoint holds step 1000's row, so the restart's series files and final
    state equal the uninterrupted run's (before, that row was missing and the restart went on
    from 1001)."""
    import filecmp
    import h5py
    assert _compress(COMPRESS + ["--out", str(tmp_path / "U")], monkeypatch) in (0, 5)
    assert _compress(COMPRESS + ["--out", str(tmp_path / "S")], monkeypatch, 975) == 128 + signal.SIGTERM
    ck = tmp_path / "S" / "checkpoints" / "checkpoint-0000001000.h5"
    assert ck.exists(), sorted(os.listdir(tmp_path / "S" / "checkpoints"))
    again = ["--quiet", "--restart", str(ck), "--steps", "1100", "--out", str(tmp_path / "R")]
    assert _compress(again, monkeypatch) in (0, 5)
    assert filecmp.cmp(tmp_path / "U" / "series.csv", tmp_path / "R" / "series.csv", shallow=False)
    last = "checkpoints/checkpoint-0000001100.h5"
    with h5py.File(tmp_path / "U" / last, "r") as u, h5py.File(tmp_path / "R" / last, "r") as r:
        ou, orr = np.argsort(u["elements/gid"][...]), np.argsort(r["elements/gid"][...])
        for k in ("x", "v", "w", "f"):
            assert np.array_equal(u["elements/" + k][...][ou], r["elements/" + k][...][orr]), k


# -- the watchdog after a stop --------------------------------------------------------------

def test_a_final_checkpoint_longer_than_the_watchdog_limit_is_written(tmp_path, monkeypatch):
    """2 ranks, ``run.watchdog_seconds = 10``, SIGTERM to mpiexec, a final checkpoint held 15 s
    (``PARDEM_CHECKPOINT_PAUSE``, as a large checkpoint on a slow file system): the stopped time
    loop says it left (``watchdog.pause``), so the watchdog does not take the ranks writing it for
    ranks that stopped progressing; the run ends with 143 and its final checkpoint. (Before, the
    watchdog aborted the job with exit 1 during the write, and the checkpoint was lost.)"""
    from test_signals import SMALL, Job, stop_lines
    monkeypatch.setenv("PARDEM_CHECKPOINT_PAUSE", "15")
    out = tmp_path / "run"
    job = Job(["-m", "pardem.drivers.compress", *SMALL, "--set", "run.watchdog_seconds=10", "--out", str(out)])
    try:
        job.wait_for("step ", timeout=300)
        job.p.send_signal(signal.SIGTERM)
        job.finish(timeout=300)
    finally:
        job.kill()
    assert job.p.returncode == 128 + signal.SIGTERM, job.stderr[-3000:]
    assert "watchdog" not in job.stderr, job.stderr[-3000:]
    (line,) = stop_lines(job)
    ck = line.split("restart with --restart ")[1].strip()
    assert "final checkpoint" in line and os.path.isfile(ck), line
