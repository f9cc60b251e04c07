"""Checkpoints and restart (issue 4): exact continuation, other rank counts, refusals, atomicity.

The uninterrupted reference runs the default case to the end with checkpoints every 500 steps.
"""
import filecmp
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from _util import ran_to_end

from pardem.drivers import compress
from pardem.io.checkpoint import CheckpointError, inspect
from pardem.io.series import read_series
from pardem.io.series_h5 import read_series_h5

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
EVERY = ["--set", "checkpoint.every_steps=500", "--set", "run.skin=0.02e-3"]
MID = "checkpoints/checkpoint-0000001500.h5"
END = "checkpoints/checkpoint-0000002090.h5"


def driver(n, args, env=None, timeout=300):
    cmd = ([MPIEXEC, "-n", str(n)] if n > 1 else []) + [sys.executable, "-m", "pardem.drivers.compress",
                                                        "--quiet", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env={**os.environ, **(env or {})})


def by_gid(path, group):
    with h5py.File(path, "r") as f:
        o = np.argsort(f[group]["gid"][...])
        return {k: f[group][k][...][o] for k in f[group] if k != "x_build"}


def assert_same_state(a, b):
    for g in ("elements", "bonds"):
        A, B = by_gid(a, g), by_gid(b, g)
        for k in A:
            assert np.array_equal(A[k], B[k]), f"/{g}/{k}"


def assert_close_series(a, b, rel=1e-9):
    A, B = read_series(a), read_series(b)
    assert A["step"] == B["step"]
    scale = max(np.abs(np.array(A[k])).max() for k in A if k.startswith("eps"))
    for k in A:
        x, y = np.array(A[k]), np.array(B[k])
        s = scale if k.startswith("eps") else max(np.abs(x).max(), 1e-300)
        assert np.abs(x - y).max() <= rel * s, k


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Uninterrupted runs on 1 and 2 ranks (the 2-rank one through parallel HDF5)."""
    tmp = tmp_path_factory.mktemp("ref")
    out = {}
    for n in (1, 2):
        d = tmp / f"n{n}"
        p = driver(n, ["--out", str(d), *EVERY])
        assert ran_to_end(p), p.stderr
        out[n] = d
    return out


@pytest.mark.parametrize("n", [1, 2])
def test_restart_same_ranks_is_bit_for_bit(reference, tmp_path, n):
    ref = reference[n]
    assert sorted(os.listdir(ref / "checkpoints")) == [
        "checkpoint-0000001500.h5", "checkpoint-0000002000.h5", "checkpoint-0000002090.h5"]   # keep = 3
    p = driver(n, ["--restart", str(ref / MID), "--out", str(tmp_path / "r")])
    assert ran_to_end(p), p.stderr
    assert filecmp.cmp(ref / "series.csv", tmp_path / "r" / "series.csv", shallow=False)
    a, b = read_series_h5(ref / "series.h5"), read_series_h5(tmp_path / "r" / "series.h5")
    assert list(a) == list(b) and all(np.array_equal(a[k], b[k]) for k in a)
    assert_same_state(ref / END, tmp_path / "r" / END)
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert s["steps"] == 2090 and s["restarted_from"].endswith("checkpoint-0000001500.h5")


@pytest.mark.mpi
@pytest.mark.parametrize("wrote, reads", [(2, 1), (1, 3)])
def test_restart_other_rank_count_agrees(reference, tmp_path, wrote, reads):
    p = driver(reads, ["--restart", str(reference[wrote] / MID), "--out", str(tmp_path / "r")])
    assert ran_to_end(p), p.stderr
    assert_close_series(reference[wrote] / "series.csv", tmp_path / "r" / "series.csv")
    A, B = by_gid(reference[wrote] / END, "elements"), by_gid(tmp_path / "r" / END, "elements")
    assert np.array_equal(A["gid"], B["gid"])
    assert np.abs(A["x"] - B["x"]).max() <= 1e-9 * np.abs(A["x"]).max()
    with h5py.File(tmp_path / "r" / END) as f:
        assert f.attrs["n_ranks"] == reads and f.attrs["n_elements"] == 9261 and f.attrs["n_bonds"] == 26460


def test_restart_steps_counts_from_the_start_and_may_change_length(reference, tmp_path):
    p = driver(1, ["--restart", str(reference[1] / MID), "--out", str(tmp_path / "a"), "--steps", "1700"])
    assert ran_to_end(p), p.stderr
    assert json.loads((tmp_path / "a" / "summary.json").read_text())["steps"] == 1700
    p = driver(1, ["--restart", str(reference[1] / MID), "--out", str(tmp_path / "b"),
                   "--set", "loading.strain=0.006", "--set", "output.series_every=7"])
    assert ran_to_end(p), p.stderr
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["steps"] > 2090


def _one_line_exit_2(p, *words):
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_refuses_bad_checkpoints(reference, tmp_path):
    good = reference[1] / MID
    truncated = tmp_path / "truncated.h5"
    data = good.read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    corrupt = tmp_path / "corrupt.h5"
    corrupt.write_bytes(b"\x00garbage" * 64 + data[512:])
    incomplete = tmp_path / "incomplete.h5"
    shutil.copy(good, incomplete)
    with h5py.File(incomplete, "r+") as f:
        f.attrs["complete"] = 0
    other_layout = tmp_path / "layout.h5"
    shutil.copy(good, other_layout)
    with h5py.File(other_layout, "r+") as f:
        f.attrs["layout_version"] = 99
    cases = [(truncated, "not a readable pardem checkpoint"), (corrupt, "not a readable pardem checkpoint"),
             (incomplete, "incomplete"), (other_layout, "layout version 99"),
             (tmp_path / "missing.h5", "no such file")]
    for path, words in cases:
        _one_line_exit_2(driver(1, ["--restart", str(path), "--out", str(tmp_path / "x")]), words)
        with pytest.raises(CheckpointError):
            inspect(str(path))


def test_refuses_a_deck_that_changes_the_physics(reference, tmp_path):
    p = driver(1, ["--restart", str(reference[1] / MID), "--out", str(tmp_path / "x"),
                   "--set", "bonds.young=2e8"])
    _one_line_exit_2(p, "bonds.young", "differs from the checkpoint")


@pytest.mark.mpi
def test_without_parallel_hdf5_ranks_take_turns(reference, tmp_path):
    """The forced serial-driver path writes the same data, and restarts bit for bit."""
    env = {"PARDEM_H5_SERIAL": "1"}
    p = driver(2, ["--out", str(tmp_path / "s"), *EVERY], env=env)
    assert ran_to_end(p), p.stderr
    assert_same_state(reference[2] / END, tmp_path / "s" / END)
    p = driver(2, ["--restart", str(tmp_path / "s" / MID), "--out", str(tmp_path / "r")], env=env)
    assert ran_to_end(p), p.stderr
    assert filecmp.cmp(reference[2] / "series.csv", tmp_path / "r" / "series.csv", shallow=False)


@pytest.mark.parametrize("n", [1, 2])
def test_sigkill_during_a_write_leaves_the_previous_checkpoint(tmp_path, n):
    out = tmp_path / "k"
    cmd = ([MPIEXEC, "-n", str(n)] if n > 1 else []) + [
        sys.executable, "-m", "pardem.drivers.compress", "--quiet", "--out", str(out),
        "--set", "checkpoint.every_steps=400"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PARDEM_CHECKPOINT_PAUSE": "30"}, start_new_session=True)
    ck = out / "checkpoints"
    first, tmp = ck / "checkpoint-0000000400.h5", ck / "checkpoint-0000000800.h5.tmp"
    try:
        deadline = time.monotonic() + 120
        # the second write has flushed its data and holds (PARDEM_CHECKPOINT_PAUSE) before the
        # completion mark: its size has reached that of the first (killing it earlier, before
        # the HDF5 header is on disk, would test a different refusal)
        while time.monotonic() < deadline and not (
                tmp.exists() and first.exists() and tmp.stat().st_size >= 0.95 * first.stat().st_size):
            assert proc.poll() is None
            time.sleep(0.1)
        time.sleep(0.5)
        assert tmp.exists() and first.exists()
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert inspect(str(first))["step"] == 400
    with pytest.raises(CheckpointError, match="incomplete"):
        inspect(str(tmp))
    p = driver(1, ["--restart", str(first), "--out", str(tmp_path / "r"), "--steps", "600"])
    assert ran_to_end(p), p.stderr


def test_periodic_in_seconds_and_at_end(tmp_path):
    args = ["--out", str(tmp_path / "t"), "--quiet", "--set", "checkpoint.every_seconds=0.2",
            "--set", "checkpoint.keep=100"]
    assert compress.main(args) == 0
    names = sorted(os.listdir(tmp_path / "t" / "checkpoints"))
    assert names[-1] == "checkpoint-0000002090.h5" and len(names) >= 2


@pytest.mark.mpi
def test_a_rank_with_nothing_to_write_does_not_hang(tmp_path):
    """Rank 0 owns no element (and no bond): the collective MPI-IO write must still complete."""
    out = tmp_path / "z"
    p = driver(2, ["--out", str(out), "--set", "domain.box=[0.004,0.004,0.004]",
                   "--set", "parallel.initial_split=[1e-5]", "--set", "parallel.balance_every=0",
                   "--set", "checkpoint.driver=mpio", "--steps", "20"], timeout=120)
    assert ran_to_end(p), p.stderr
    meta = inspect(str(out / "checkpoints" / "checkpoint-0000000020.h5"))
    assert list(meta["owned_counts"]) == [0, 512] and meta["n_bonds"] == 1344
    p = driver(2, ["--restart", str(out / "checkpoints" / "checkpoint-0000000020.h5"), "--steps", "30",
                   "--out", str(tmp_path / "r")], timeout=120)
    assert ran_to_end(p), p.stderr


def test_restart_refuses_steps_before_the_checkpoint(reference, tmp_path):
    p = driver(1, ["--restart", str(reference[1] / MID), "--out", str(tmp_path / "x"), "--steps", "1000"])
    _one_line_exit_2(p, "--steps 1000", "before the checkpoint's step 1500")


def test_restart_writes_its_own_folder_and_prunes_only_its_checkpoints(reference, tmp_path):
    """A restart without --out writes into a new sibling folder (never into the original run's),
    keeps only its own newest ``checkpoint.keep`` checkpoints there, and leaves every file of the
    original run as it was."""
    run = tmp_path / "copy"
    shutil.copytree(reference[1], run)
    before = {name: (run / "checkpoints" / name).read_bytes() for name in os.listdir(run / "checkpoints")}
    summary_before = (run / "summary.json").read_bytes()
    p = driver(1, ["--restart", str(run / MID), "--set", "checkpoint.every_steps=100",
                   "--set", "checkpoint.keep=2"])
    assert ran_to_end(p), p.stderr
    new = [d for d in os.listdir(tmp_path) if d.startswith("copy-restart-")]
    assert len(new) == 1, os.listdir(tmp_path)
    s = json.loads((tmp_path / new[0] / "summary.json").read_text())
    assert [os.path.basename(x) for x in s["checkpoints"]] == ["checkpoint-0000002000.h5",
                                                               "checkpoint-0000002090.h5"]
    assert sorted(os.listdir(tmp_path / new[0] / "checkpoints")) == ["checkpoint-0000002000.h5",
                                                                    "checkpoint-0000002090.h5"]
    after = {name: (run / "checkpoints" / name).read_bytes() for name in os.listdir(run / "checkpoints")}
    assert after == before and (run / "summary.json").read_bytes() == summary_before


def test_restart_into_the_original_folder_is_refused(reference, tmp_path):
    run = tmp_path / "copy"
    shutil.copytree(reference[1], run)
    for extra in ([], ["--overwrite"]):
        p = driver(1, ["--restart", str(run / MID), "--out", str(run), *extra])
        assert p.returncode == 2 and p.stderr.count("\n") == 1 and "Traceback" not in p.stderr, p.stderr
