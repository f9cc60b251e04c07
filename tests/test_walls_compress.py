"""Walls in the compression test (issue 5, walls): frictionless plates hold a tilted anisotropic
domain whose loaded faces are flat; the wall friction history migrates between ranks and is
restored bit for bit from checkpoints."""
import filecmp
import json
import math
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


def test_a_tilted_domain_stays_between_frictionless_plates(tmp_path):
    """The tilted lattice's loaded faces are flat (``domains.ordered``), so frictionless plates hold it
    while it shears: both plates carry the load (their forces agree within 10 %: the domain's inertia
    at the end of a quasi-static run), secant and slope moduli agree (10 %), and the modulus is the
    orthotropic lattice's off-axis value at 30 deg (beam theory, nu = 0) less the staircase side faces'
    boundary layer, at most 1.75 rows of the 8 across (tests/test_anisotropy_study.py BOUNDARY_ROWS)."""
    driver(1, TILTED + ["--out", str(tmp_path / "free")])
    free = summary(tmp_path / "free")
    assert free["plate_force"] > 0 and free["plate_force_moving"] == pytest.approx(free["plate_force"], rel=0.1)
    assert free["young_modulus_secant"] == pytest.approx(free["young_modulus"], rel=0.1)
    EL, ER = math.pi / 4 * 100e6, math.pi / 4 * 5e6                    # pi/4 E r^2, r = 1
    G = 3 * math.pi / 16 * 100e6 * 5e6 / 105e6                         # LR bonds bending in series
    c2, s2 = math.cos(math.radians(30.0)) ** 2, math.sin(math.radians(30.0)) ** 2
    orthotropic = 1.0 / (c2 * c2 / EL + s2 * s2 / ER + s2 * c2 / G)
    assert abs(free["young_modulus"] / orthotropic - 1.0) < 1.75 / 8


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
