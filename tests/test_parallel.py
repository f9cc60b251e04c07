"""The slab decomposition, run as ``mpiexec -n K`` subprocesses (issue 3).

Results on 1, 2 and 3 ranks agree to within 1e-9 of each series' largest magnitude; migration keeps
every element and bond exactly once and unaltered; ghosts equal their owners after every step;
unbalanced slabs rebalance; a failure on one rank ends every rank quickly.
"""
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from _util import ran_to_end

from pardem.io.series import read_series

pytestmark = pytest.mark.mpi
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
HERE = os.path.dirname(__file__)
STRAINS = ("eps_xx", "eps_yy", "eps_zz", "eps_xy", "eps_xz", "eps_yz")


def mpirun(n, args, timeout=300, env=None):
    cmd = [MPIEXEC, "-n", str(n), sys.executable] + args
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def compress(tmp_path, n, name, extra=()):
    """The default case; a small skin makes the ghost layers rebuild several times during it."""
    out = tmp_path / name
    p = mpirun(n, ["-m", "pardem.drivers.compress", "--quiet", "--out", str(out),
                   "--set", "run.skin=0.02e-3", *extra])
    assert ran_to_end(p), p.stderr
    return json.loads((out / "summary.json").read_text()), read_series(out / "series.csv")


def assert_series_agree(a, b, rel=1e-9):
    """Forces and plate motion within rel of each series' largest magnitude; strains within rel of
    the largest strain component (shear strains are round-off noise on both sides)."""
    assert a["step"] == b["step"]
    for k in ("time", "plate_displacement", "force_fixed", "force_moving"):
        x, y = np.array(a[k]), np.array(b[k])
        assert np.abs(x - y).max() <= rel * np.abs(x).max(), k
    scale = max(np.abs(np.array(a[k])).max() for k in STRAINS)
    for k in STRAINS:
        assert np.abs(np.array(a[k]) - np.array(b[k])).max() <= rel * scale, k


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("serial")
    return {axis: compress(tmp, 1, f"one-{axis}", ["--set", f"parallel.slab_axis={axis}"])
            for axis in ("y", "x")}


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("axis", ["y", "x"])
def test_ranks_agree_with_one_rank(serial, tmp_path, n, axis):
    """The default case, slabs across (y) or along (x: elements migrate) the load."""
    s1, ser1 = serial[axis]
    sn, sern = compress(tmp_path, n, f"{n}-{axis}", ["--set", f"parallel.slab_axis={axis}"])
    assert sn["n_ranks"] == n and sn["slab_axis"] == axis
    assert sn["n_elements_end"] == sn["n_elements"] == s1["n_elements"] == 9261
    assert sn["n_bonds_end"] == sn["n_bonds"] == s1["n_bonds"] == 26460
    owned = [r["owned_elements"] for r in sn["per_rank"]]
    assert sum(owned) == 9261 and max(owned) - min(owned) <= 0.05 * np.mean(owned)
    assert all(r["ghost_elements"] > 0 and r["rebuilds"] > 0 for r in sn["per_rank"])
    assert_series_agree(ser1, sern)
    assert sn["young_modulus"] == pytest.approx(s1["young_modulus"], rel=1e-9)


@pytest.mark.parametrize("n", [2, 3])
def test_migration_keeps_every_element_and_bond(tmp_path, n):
    out = tmp_path / "mig.json"
    p = mpirun(n, [os.path.join(HERE, "mpi", "migrate.py"), str(out)])
    assert ran_to_end(p), p.stderr
    r = json.loads(out.read_text())
    assert r["rebuilds"] > 100 and r["travel_in_slab_widths"] >= 1.0
    assert r["total_owned"] == r["unique_elements"] == r["n_elements"]
    assert r["unique_bonds_held"] == r["n_bonds"] and r["missing_bonds"] == 0
    assert r["altered"] == []
    assert r["x_error"] < 1e-10 and r["v_error"] < 1e-10 and r["q_error"] < 1e-12
    assert r["owned_counts"][0] == 0          # everything left the first slab


@pytest.mark.parametrize("n", [2, 3])
def test_ghosts_equal_owners_after_every_step(tmp_path, n):
    out = tmp_path / "ghosts.json"
    p = mpirun(n, [os.path.join(HERE, "mpi", "ghosts.py"), str(out), "400"])
    assert ran_to_end(p), p.stderr
    r = json.loads(out.read_text())
    assert r["steps"] == 400 * n and r["rebuilds"] > 3 and r["ghosts_checked"] > 0
    assert r["mismatches"] == 0 and r["missing_ghosts"] == 0


@pytest.mark.parametrize("n, split, by", [(2, "[0.2]", "count"), (3, "[0.15, 0.3]", "count"),
                                          (2, "[0.2]", "time")])
def test_unbalanced_slabs_rebalance(serial, tmp_path, n, split, by):
    s, ser = compress(tmp_path, n, "unbalanced", ["--set", f"parallel.initial_split={split}",
                                                  "--set", "parallel.balance_every=100",
                                                  "--set", f"parallel.balance_by={by}",
                                                  "--set", "parallel.slab_axis=y"])
    assert all(r["rebalances"] >= 1 for r in s["per_rank"])
    if by == "count":
        owned = [r["owned_elements"] for r in s["per_rank"]]
        assert max(owned) - min(owned) <= 0.05 * np.mean(owned)
    assert s["n_elements_end"] == 9261 and s["n_bonds_end"] == 26460
    assert_series_agree(serial["y"][1], ser)


@pytest.mark.parametrize("n, rank", [(2, 1), (3, 0)])
def test_failure_on_one_rank_ends_all(tmp_path, n, rank):
    t0 = time.monotonic()
    p = mpirun(n, ["-m", "pardem.drivers.compress", "--quiet", "--out", str(tmp_path / "f")],
               timeout=60, env={"PARDEM_FAULT": f"{rank}:60"})
    elapsed = time.monotonic() - t0
    assert p.returncode != 0
    assert p.stderr.count(f"fault injected on rank {rank} at step 60") == 1
    assert elapsed < 10 + 5, elapsed      # start-up (imports) plus the 10 s allowed


def test_too_many_ranks_for_the_domain_is_bad_input(tmp_path):
    """Slabs thinner than the ghost range: one line and exit 2 on every rank, nothing run."""
    p = mpirun(3, ["-m", "pardem.drivers.compress", "--quiet", "--out", str(tmp_path / "o"),
                   "--set", "domain.box=[0.002,0.002,0.002]"], timeout=120)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "use fewer ranks" in lines[0] and "Traceback" not in p.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("n", [1, 2])
def test_unstable_run_stops_every_rank_with_exit_3(tmp_path, n):
    """A blow-up (time step 20x the true bound) ends all ranks with exit 3 and one message, and
    no checkpoint of the blown-up state is kept (checkpoints were due every 10 steps)."""
    out = tmp_path / "u"
    p = mpirun(n, [os.path.join(HERE, "mpi", "unstable.py"), "20", "--quiet", "--out", str(out),
                   "--set", "domain.box=[0.006,0.004,0.004]", "--steps", "400",
                   "--set", "checkpoint.every_steps=10"], timeout=120)
    assert p.returncode == 3, p.stderr
    assert p.stderr.count("became unstable") == 1 and "Traceback" not in p.stderr
    import h5py
    names = os.listdir(out / "checkpoints")
    assert names                      # some were written before the blow-up
    for name in names:
        with h5py.File(out / "checkpoints" / name) as f:
            assert np.all(np.isfinite(f["elements/v"][...])), name
