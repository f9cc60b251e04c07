"""The stage loop of the multi-stage protocols (``pardem.protocols.stages``) and the biaxial
driver's stops and restarts in every stage.

Oracles: the uninterrupted run of the same deck on the same ranks (an independent computation:
a restart that resumed anything differently, FIRE's counters or step, the servo, the contact
history, the membrane's chains, would change the final state's bits), compared through the final
checkpoint's state by gid (positions, velocities, spins, orientations, forces, torques and the
contact histories, exactly) and the series and summary (every float of the JSON, 17 digits).
"""
import csv
import json
import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from pardem.protocols import stages
from pardem.protocols.granular_output import StepLimit

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHORT = os.path.join(ROOT, "drivers", "biaxial_short.toml")
EVERY = 130       # checkpoint period [steps]: not a multiple of the checks (200) nor of the servo's (10)
# the short deck shrunk: 100 grains, a preparation capped at 3000 steps (not converged: the
# restart, not the physics, is tested; measured: settles and loads without a membrane failure),
# the settling 3000 .. 3100, the loading 3100 .. 3992 sampled every 4 steps (892 // 223),
# membranes rebuilt every 50 steps
TINY = ["--config", SHORT, "--set", "sample.n=100", "--set", "preparation.max_steps=3000",
        "--set", "preparation.max_rate=2e4", "--set", "preparation.servo_rate=2e4",
        "--set", "loading.strain=0.004", "--set", "loading.settle_steps=100", "--set", "loading.membrane_every=50",
        "--set", "localisation.strains=[0.004]", "--set", "localisation.window=0.002",
        "--set", "output.samples=223", "--set", "output.plot=false", "--set", f"checkpoint.every_steps={EVERY}",
        "--set", "checkpoint.keep=100000", "--set", "checkpoint.every_seconds=0"]
PREP_END, SETTLE_END = 3000, 3100
FIELDS = ("x", "v", "w", "q", "f", "t")


def _command(args, out):
    return [sys.executable, "-m", "pardem.drivers.biaxial", "--quiet"] + args + ["--out", str(out)]


def _run(args, out):
    """The biaxial driver on 1 rank; its summary."""
    p = subprocess.run(_command(args, out), capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-3000:]
    return json.loads((out / "biaxial.json").read_text())


def _state(path):
    """The state of a checkpoint by gid: element arrays and the live contact histories."""
    with h5py.File(path, "r") as f:
        g = f["elements/gid"][...]
        o = np.argsort(g)
        out = {k: f["elements/" + k][...][o] for k in FIELDS}
        out["gid"] = g[o]
        gi, gj, h = f["contacts/gid_i"][...], f["contacts/gid_j"][...], f["contacts/history"][...]
        live = np.any(h != 0.0, axis=1)
        keys, first = np.unique(gi[live] * (1 << 31) + gj[live], return_index=True)
        out["pair_keys"], out["history"] = keys, h[live][first]
        out["step"], out["time"] = int(f.attrs["step"]), float(f.attrs["time"])
    return out


def _same_state(a, b):
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def _rows(out):
    with open(out / "biaxial.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _results(summary):
    """The pressures' results without the wall times."""
    res = json.loads(json.dumps(summary["pressures"]))
    for r in res:
        r["preparation"].pop("seconds")
    return res


def _checkpoint(out, step):
    return out / "checkpoints" / f"checkpoint-{step:010d}.h5"


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    """The uninterrupted tiny run: its folder and summary."""
    out = tmp_path_factory.mktemp("stages") / "full"
    s = _run(TINY, out)
    assert s["finished"] and s["stage_steps"]["prepare"] == PREP_END and s["steps"] > SETTLE_END + 500, s["stage_steps"]
    return out, s


def _same_as_full(full, out, s):
    fo, fs = full
    assert s["finished"] and s["steps"] == fs["steps"]
    _same_state(_state(_checkpoint(fo, fs["steps"])), _state(_checkpoint(out, s["steps"])))
    assert _rows(out) == _rows(fo)
    assert _results(s) == _results(fs)


def test_run_stages_resumes_the_named_stage_and_passes_a_stop_through():
    """``run_stages``: from the state's stage on, ``resume`` for the first only, a returned name
    jumps, a ``StepLimit`` leaves the state at its stage; unknown names are refused."""
    calls = []

    def stage(name, nxt=None, stop=False):
        def run(resume):
            calls.append((name, resume))
            if stop:
                raise StepLimit(name)
            return nxt
        return run
    st = {"stage": "b"}
    stages.run_stages(st, [("a", stage("a")), ("b", stage("b")), ("c", stage("c"))], resume=True)
    assert calls == [("b", True), ("c", False)] and st["stage"] == stages.DONE
    calls.clear()
    st = {"stage": "a"}
    with pytest.raises(StepLimit):
        stages.run_stages(st, [("a", stage("a", nxt="c")), ("b", stage("b")), ("c", stage("c", stop=True))])
    assert calls == [("a", False), ("c", False)] and st["stage"] == "c"
    with pytest.raises(ValueError, match="unknown stage 'x'"):
        stages.run_stages({"stage": "x"}, [("a", stage("a"))])
    with pytest.raises(ValueError, match="distinct"):
        stages.run_stages({"stage": "a"}, [("a", stage("a")), ("a", stage("a"))])


def test_steps_stops_the_biaxial_preparation_at_that_step(tmp_path):
    """``--steps 7`` stops the run at step 7, inside the preparation, with a checkpoint of it
    (the driver used to run the whole preparation first)."""
    s = _run(TINY + ["--steps", "7"], tmp_path / "a")
    assert not s["finished"] and s["steps"] == 7 and "--steps 7" in s["stopped"]
    assert s["checkpoints"][-1].endswith("checkpoint-0000000007.h5")
    with h5py.File(s["checkpoints"][-1], "r") as f:
        state = json.loads(f.attrs["protocol"])
    cur = state["current"]
    assert cur["stage"] == "prepare" and cur["sweep"]["fire"]["calls"] == 7


def test_biaxial_restarts_in_every_stage_equal_the_uninterrupted_run(full, tmp_path):
    """From the uninterrupted run's periodic checkpoint inside the preparation (step 1300, off
    the checks), stopped by --steps inside the preparation off the checks and off the servo
    stiffness' period (2055), at a membrane rebuild of the settling (3050), at one of the loading
    (3500) and between two (3777), and restarted each time: the same final state, series and
    results as the uninterrupted run, bit for bit."""
    fo, fs = full
    start = _checkpoint(fo, 10 * EVERY)
    assert start.exists()       # the preparation writes the periodic checkpoints
    previous = start
    for i, stop in enumerate([2055, 3050, 3500, 3777, None]):
        out = tmp_path / f"r{i}"
        s = _run(["--restart", str(previous)] + ([] if stop is None else ["--steps", str(stop)]), out)
        if stop is not None:
            assert not s["finished"] and s["steps"] == stop, s["stopped"]
            previous = _checkpoint(out, stop)
            assert previous.exists()
    _same_as_full(full, out, s)


@pytest.mark.parametrize("written, stopped, stage", [(520, 550, "prepare"), (3250, 3300, "load")])
def test_a_stop_signal_restarts_as_the_uninterrupted_run(full, tmp_path, written, stopped, stage):
    """SIGTERM while the checkpoint of step ``written`` is being written (held open by
    ``PARDEM_CHECKPOINT_PAUSE``): the run stops at the next stability check (every 50 steps),
    ``stopped``, with 128 + 15 and a checkpoint there: in the preparation at a step of the servo
    stiffness' update (550), in the loading at a sample and a membrane rebuild (3300), the steps
    whose operations a signal leaves undone. --restart from it gives the uninterrupted run's final
    state, series and results, bit for bit."""
    out = tmp_path / "killed"
    args = TINY + ["--set", f"checkpoint.every_steps={written}"]
    p = subprocess.Popen(_command(args, out), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env={**os.environ, "PARDEM_CHECKPOINT_PAUSE": "2"})
    try:
        deadline = time.time() + 600
        while (not list((out / "checkpoints").glob(f"checkpoint-{written:010d}*")) if (out / "checkpoints").exists()
               else True) and p.poll() is None and time.time() < deadline:
            time.sleep(0.02)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=600)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 128 + signal.SIGTERM, err[-3000:]
    s = json.loads((out / "biaxial.json").read_text())
    assert s["interrupted"]["signal"] == signal.SIGTERM and not s["finished"]
    last = s["checkpoints"][-1]
    with h5py.File(last, "r") as f:
        assert int(f.attrs["step"]) == stopped
        assert json.loads(f.attrs["protocol"])["current"]["stage"] == stage
    again = _run(["--restart", last], tmp_path / "again")
    _same_as_full(full, tmp_path / "again", again)
