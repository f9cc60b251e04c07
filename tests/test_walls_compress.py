"""Walls in the compression test (issue 5, walls): frictional plates hold a tilted anisotropic
domain that frictionless plates let slide out; the wall friction history migrates between ranks
and is restored bit for bit from checkpoints."""
import filecmp
import json
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from _util import ran_to_end

from pardem.io.series import read_series

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
HERE = os.path.dirname(__file__)
DECK = os.path.join(HERE, "..", "drivers", "anisotropy_ordered.toml")
# a 4 mm cube tilted by 30 deg with E_L / E_R = 20: under load it shears in the LR plane
TILTED = ["--config", DECK, "--set", "domain.tilt_deg=30", "--set", "domain.box=[0.004,0.004,0.004]",
          "--set", "bonds.young=[100e6,5e6,5e6]"]


def driver(n, args, timeout=300):
    cmd = ([MPIEXEC, "-n", str(n)] if n > 1 else []) + [sys.executable, "-m", "pardem.drivers.compress",
                                                        "--quiet", *args]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert ran_to_end(p), p.stderr[-3000:]
    return p


def summary(d):
    return json.loads((d / "summary.json").read_text())


def test_friction_keeps_a_shearing_domain_between_the_plates(tmp_path):
    driver(1, TILTED + ["--out", str(tmp_path / "free")])
    driver(1, TILTED + ["--set", "plates.friction=0.5", "--out", str(tmp_path / "held")])
    free, held = summary(tmp_path / "free"), summary(tmp_path / "held")
    # frictionless: the domain slides out sideways and the fixed plate ends up unloaded
    assert abs(free["young_modulus_secant"]) < 0.05 * free["young_modulus"]
    # with friction the fixed plate carries the load: secant and slope moduli agree
    assert held["young_modulus_secant"] == pytest.approx(held["young_modulus"], rel=0.1)
    assert held["young_modulus"] > 0


@pytest.mark.mpi
def test_wall_friction_history_migrates_and_restarts_bit_for_bit(tmp_path):
    """Hertz plates and lateral walls with friction, slabs along the load (elements migrate)."""
    args = TILTED + ["--set", "plates.friction=0.5", "--set", "plates.law=hertz",
                     "--set", "plates.lateral_walls=true", "--set", "plates.restitution=0.5",
                     "--set", "parallel.slab_axis=x", "--set", "run.skin=0.005e-3",
                     "--set", "checkpoint.every_steps=400"]
    driver(1, args + ["--out", str(tmp_path / "one")])
    driver(2, args + ["--out", str(tmp_path / "two")])
    a, b = read_series(tmp_path / "one" / "series.csv"), read_series(tmp_path / "two" / "series.csv")
    for k in ("force_fixed", "force_moving"):
        x, y = np.array(a[k]), np.array(b[k])
        assert np.abs(x - y).max() <= 1e-9 * np.abs(x).max(), k
    assert summary(tmp_path / "two")["per_rank"][0]["rebuilds"] > 0
    cks = sorted(os.listdir(tmp_path / "two" / "checkpoints"))
    mid = tmp_path / "two" / "checkpoints" / cks[0]
    with h5py.File(mid) as f:
        h = f["elements"]["wall_h"][...]
        assert h.shape[1] == 6 and np.count_nonzero(h) > 0      # plates and 4 lateral walls
    driver(2, ["--restart", str(mid), "--out", str(tmp_path / "again")])
    assert filecmp.cmp(tmp_path / "two" / "series.csv", tmp_path / "again" / "series.csv", shallow=False)
