"""A restarted run's outputs read as one run (compress driver, ParaView every 200 steps,
checkpoints every 500): the last run's ``pardem.pvd`` lists every step of the whole run once, the
snapshots of the earlier runs up to the checkpoint restarted from and its own after it, and their
files hold the uninterrupted run's data; the series files of the last run equal the uninterrupted
run's (a restart rewrites them from the rows its checkpoint kept)."""
import filecmp
import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from _util import ran_to_end

from pardem.io.paraview import read_pvd, step_of
from pardem.io.series_h5 import read_series_h5

ARGS = ["--set", "checkpoint.every_steps=500", "--set", "run.skin=0.02e-3", "--set", "output.vtk_every=200",
        "--set", "output.series_every=10"]   # else --steps would change the sampling period


def driver(*args):
    return subprocess.run([sys.executable, "-m", "pardem.drivers.compress", "--quiet", *ARGS,
                           *[str(a) for a in args]], capture_output=True, text=True, timeout=600)


def pieces(pvtu):
    """The bytes of the pieces a .pvtu lists (paths relative to it)."""
    base = os.path.dirname(pvtu)
    root = ET.parse(pvtu).getroot()
    return [open(os.path.join(base, p.get("Source")), "rb").read()
            for p in root.iter("Piece") if p.get("Source")]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """U uninterrupted; A stopped at 1700 (its last checkpoint at 1500 kept, no final one);
    B restarted from A's 1500, stopped at 1900 with a final checkpoint; C restarted from B's 1900
    to the end."""
    d = tmp_path_factory.mktemp("restart_outputs")
    assert ran_to_end(driver("--out", d / "U"))
    p = driver("--out", d / "A", "--steps", 1700, "--set", "checkpoint.at_end=false")
    assert p.returncode == 0, p.stderr
    p = driver("--out", d / "B", "--restart", d / "A" / "checkpoints" / "checkpoint-0000001500.h5",
               "--steps", 1900, "--set", "checkpoint.at_end=true")   # A's deck said false
    assert p.returncode == 0, p.stderr
    p = driver("--out", d / "C", "--restart", d / "B" / "checkpoints" / "checkpoint-0000001900.h5")
    assert ran_to_end(p), p.stderr
    return d


def test_the_last_collection_lists_every_step_once(runs):
    d = runs
    full = read_pvd(d / "U" / "paraview" / "pardem.pvd")
    steps = [step_of(f) for _, f in full]
    assert steps == list(range(0, 2001, 200)) + [2090]
    # A wrote 1600 and its last step 1700 after its checkpoint at 1500: B dropped them and wrote
    # its own 1600
    assert [step_of(f) for _, f in read_pvd(d / "A" / "paraview" / "pardem.pvd")][-2:] == [1600, 1700]
    assert [step_of(f) for _, f in read_pvd(d / "B" / "paraview" / "pardem.pvd")] == \
        list(range(0, 1801, 200)) + [1900]
    last = read_pvd(d / "C" / "paraview" / "pardem.pvd")
    # C's list: every step of U, in order, once (1900 was B's at_end snapshot before C's start)
    assert [step_of(f) for _, f in last] == sorted(steps + [1900])
    times = dict((step_of(f), t) for t, f in full)
    where = {}
    for t, f in last:
        s = step_of(f)
        path = os.path.normpath(os.path.join(d / "C" / "paraview", f))
        assert os.path.isfile(path), f
        where[s] = os.path.basename(os.path.dirname(os.path.dirname(path)))
        if s in times:
            assert t == times[s]
            # the same state, the same bytes: a restart continues bit for bit
            assert pieces(path) == pieces(d / "U" / "paraview" / os.path.basename(f)), f
    assert {s for s, run in where.items() if run == "A"} == set(range(0, 1401, 200))
    assert {s for s, run in where.items() if run == "B"} == {1600, 1800, 1900}
    assert {s for s, run in where.items() if run == "C"} == {2000, 2090}


def test_the_last_series_is_the_uninterrupted_one(runs):
    d = runs
    assert filecmp.cmp(d / "U" / "series.csv", d / "C" / "series.csv", shallow=False)
    a, b = read_series_h5(d / "U" / "series.h5"), read_series_h5(d / "C" / "series.h5")
    assert list(a) == list(b) and all(np.array_equal(a[k], b[k]) for k in a)
