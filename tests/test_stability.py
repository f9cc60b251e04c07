"""The stability check covers every evolving field (issue 16, item 1), and PARDEM_FAULT is validated.

The finiteness kernel is compared with numpy's ``isfinite`` (an independent computation); the
check is exercised on each field of a small bonded run and a small granular one; the blown-up
2-rank compression of issue 16 must exit 3 and keep no checkpoint holding a NaN or infinity.
"""
import glob
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from pardem.config import DeckError
from pardem.domains.ordered import ordered_lattice
from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.errors import InstabilityError
from pardem.engine.simulation import FaultInjection, Simulation
from pardem.engine.state import Elements, Plates
from pardem.io.checkpoint import ALLOW_INF, inspect
from pardem.parallel.communicator import Communicator
from pardem.physics.finite import count_nan, count_nonfinite, first_nonfinite
from _util import granular_case

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")


def test_kernel_counts_what_numpy_counts():
    rng = np.random.default_rng(7)
    for n in (0, 1, 7, 1000, 100003):
        a = rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, size=n)
        if n:
            k = rng.integers(0, n, size=max(1, n // 100))
            a[k] = rng.choice([np.nan, np.inf, -np.inf, 5e-324, 1.7e308, -0.0], size=len(k))
        assert count_nonfinite(a) == int(np.count_nonzero(~np.isfinite(a)))
        assert count_nan(a) == int(np.count_nonzero(np.isnan(a)))
    # every NaN payload (quiet, signalling, negative) is caught, not only numpy's default one
    bits = np.array([0x7FF8000000000000, 0x7FF0000000000001, 0xFFF8000000000000, 0xFFFFFFFFFFFFFFFF,
                     0x7FEFFFFFFFFFFFFF], dtype=np.uint64)
    assert count_nonfinite(bits.view(np.float64)) == 4


def test_first_nonfinite_picks_the_array_and_respects_allowed_infinities():
    ok = np.ones((4, 3))
    assert first_nonfinite([ok, np.arange(5), np.zeros((0, 3))]) == -1
    inf = ok.copy()
    inf[2, 1] = np.inf
    assert first_nonfinite([ok, inf]) == 1
    assert first_nonfinite([ok, inf], allow_inf={1}) == -1
    nan = ok.copy()
    nan[3, 2] = np.nan
    assert first_nonfinite([ok, inf, nan], allow_inf={1, 2}) == 2
    assert first_nonfinite([ok[:, 1:], nan.T]) == 1          # non-contiguous views too


def bonded_sim():
    R = 0.25e-3
    pos, pairs, frame = ordered_lattice([8 * R] * 3, R)
    e = Elements.from_spheres(pos, R, 1000.0)
    b = make_bonds(e, pairs, BeamMaterial(young=1e8, radius_ratio=1.0, poisson=0.3, damping=0.0), frame)
    e.v[:] = np.random.default_rng(1).normal(size=e.v.shape) * 1e-3
    plates = Plates.pair(0, -1.0, 1.0, 0.0, 1.0)
    return Simulation(Communicator(), e, b, plates, 1e-9, max_speed=10.0)


def granular_sim():
    R = 0.5e-3
    L = 6 * R
    pos = np.array([[R, R, R], [2.9 * R, R, R], [R, 2.95 * R, 1.5 * R]])
    case = granular_case(Communicator(), pos, np.full(3, R), 2500.0, "hertz_mindlin",
                          {"young": 72e9, "poisson": 0.2, "friction": 0.5}, np.zeros(3), np.full(3, L),
                          1e-9, 0.05 * R)
    case.sim.elements.v[1] = [0.0, 1e-2, 0.0]   # sliding: the tangential spring loads
    return case.sim


@pytest.mark.parametrize("make", [bonded_sim, granular_sim])
def test_a_nan_or_inf_in_any_evolving_field_is_caught(make):
    """Each field alone: the speed check of the kick cannot see a NaN in w, q, f, t or the state."""
    sim = make()
    sim.run(3)
    sim.check_stability()                                    # a sane state passes
    fields = sim.evolving_fields()
    names = [n for n, _ in fields]
    assert {"x", "v", "w", "q", "f", "t"} <= set(names)
    assert ("bond plastic strain" in names) == (make is bonded_sim)
    assert ("contact history" in names) == (make is granular_sim)
    if make is granular_sim:
        assert sim.contacts.history.size and np.any(sim.contacts.history != 0)   # a loaded spring
    for name, a in fields:
        for bad in (np.nan, np.inf, -np.inf):
            flat = a.reshape(-1)
            old = flat[-1]
            flat[-1] = bad
            assert np.shares_memory(flat, a)
            with pytest.raises(InstabilityError, match="non-finite"):
                sim.check_stability()
            flat[-1] = old
            sim._unstable = False
    sim.check_stability()


def test_fault_injection_environment_is_validated(monkeypatch):
    for good, expect in (("1:200", (1, 200)), (" 0:0 ", (0, 0))):
        monkeypatch.setenv("PARDEM_FAULT", good)
        f = FaultInjection.from_environment()
        assert (f.rank, f.step) == expect
    monkeypatch.setenv("PARDEM_FAULT", "")
    assert FaultInjection.from_environment() is None
    for bad in ("1", "a:b", "1:2:3", "-1:5", "1:2.5", "1:", ":3", "١:٢"):
        monkeypatch.setenv("PARDEM_FAULT", bad)
        with pytest.raises(DeckError, match="PARDEM_FAULT") as err:
            FaultInjection.from_environment()
        assert "RANK:STEP" in str(err.value) and "\n" not in str(err.value)


def _nonfinite_datasets(path):
    bad = []
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and obj.dtype.kind == "f" and obj.size:
                a = obj[...]
                g, n = name.split("/", 1)
                if np.isnan(a).any() or ((g, n) not in ALLOW_INF and np.isinf(a).any()):
                    bad.append(name)
        f.visititems(visit)
    return bad


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_blown_up_run_keeps_no_nonfinite_checkpoint(tmp_path):
    """Issue 16's case: on 2 ranks, dt at the critical step and a 120 m/s plate blow the lattice up
    (NaN in w and t before any speed exceeds the limit); it must end with exit 3, one message,
    and every checkpoint it kept must be finite and verify."""
    out = tmp_path / "blow"
    cmd = [MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.compress", "--quiet",
           "--set", "run.dt=1.43e-7", "--set", "loading.plate_speed=120", "--set", "checkpoint.every_steps=20",
           "--steps", "3000", "--out", str(out)]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert p.returncode == 3, p.stderr
    assert "unstable" in p.stderr.lower() or "nan" in p.stderr.lower(), p.stderr
    kept = sorted(glob.glob(str(out / "checkpoints" / "*.h5")))
    assert kept, "the run wrote checkpoints before blowing up"
    assert not glob.glob(str(out / "checkpoints" / "*.tmp"))
    for path in kept:
        assert _nonfinite_datasets(path) == [], path
        inspect(path)
    assert all(os.path.getsize(p) > 0 for p in kept)
