"""The benchmarks/ scripts run, shortened, as a user reruns them, and their JSON says what was run.

Timings are not asserted (performance is measured by the benchmarks themselves, never in tests);
what is asserted is that each script still runs against today's engine (``profile_compress.py``
once passed the bond loop an argument it no longer took, and nothing noticed) and that the counts
it reports match the case as built: a simple cubic lattice of n^3 elements has 3 n^2 (n - 1)
nearest-neighbour bonds when open, and 3 n^3 touching pairs when periodic on all axes.
"""
import json
import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
SHORT = ["--warmup", "5", "--steps", "20"]


def run(script, *args, timeout=900):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", script), *map(str, args)],
                         capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    return res


def load(path):
    with open(path) as fh:
        return json.load(fh)


def assert_rate(row):
    # element-steps per second is elements x steps / seconds, as the README defines it (1e-9:
    # round-off of the script's own division)
    assert row["seconds"] > 0
    assert row["element_steps_per_second"] == pytest.approx(row["elements"] * row["steps"] / row["seconds"],
                                                            rel=1e-9)


def test_bench_bond(tmp_path):
    out = tmp_path / "bond.json"
    run("bench_bond.py", "--sizes", 6, *SHORT, "--out", out)
    row, = load(out)["results"]
    assert (row["elements"], row["bonds"], row["steps"]) == (6 ** 3, 3 * 6 ** 2 * 5, 20)
    assert_rate(row)


def test_bench_gran(tmp_path):
    out = tmp_path / "gran.json"
    run("bench_gran.py", "--sizes", 6, *SHORT, "--out", out)
    row, = load(out)["results"]
    # spacing 1.998 R: every element touches its 6 lattice neighbours, periodic on all axes
    assert (row["elements"], row["contacts"]) == (6 ** 3, 3 * 6 ** 3)
    assert_rate(row)


def test_bench_neighbours(tmp_path):
    out = tmp_path / "neighbours.json"
    run("bench_neighbours.py", "--sizes", 8, "--repeat", 1, "--out", out)
    row, = load(out)["results"]
    # skin 0.2 R: the face-diagonal neighbours (2.83 R) stay out of the list
    assert (row["elements"], row["pairs"]) == (8 ** 3, 3 * 8 ** 3)


def test_bench_checkpoint(tmp_path):
    out = tmp_path / "checkpoint.json"
    run("bench_checkpoint.py", "--sizes", 8, "--out", out, "--scratch", tmp_path / "scratch")
    row, = load(out)["results"]
    assert row["elements"] == 8 ** 3
    assert row["file_bytes"] > 0 and row["write_seconds"] > 0 and row["restart_seconds"] > 0


def test_scaling_one_rank(tmp_path):
    out = tmp_path / "scaling.json"
    run("scaling.py", "--strong-n", 8, "--weak-n", 6, *SHORT, "--out", out)
    rows = load(out)["results"]
    strong = [r for r in rows if r["kind"] == "strong"]
    assert [(r["ranks"], r["elements"], r["bonds"]) for r in strong] == [(1, 8 ** 3, 3 * 8 ** 2 * 7)]
    for r in rows:
        assert_rate(r)


def test_profile_gran():
    res = run("profile_gran.py", "--n", 8, "--steps", 20, "--repeats", 1)
    assert res.stdout.strip()


def shear_packing_8000():
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    import shear_case
    return shear_case.packing_path(8000)


@pytest.mark.skipif(not os.path.exists(shear_packing_8000()), reason="the shared GRAN-SHEAR packings "
                    "(../shared/peers/shear/packings) are not on this machine")
def test_compare_peers_shear_without_peers(tmp_path):
    """GRAN-SHEAR (N = 8,000, shortened) through compare_peers: the run counts its elements and
    reports the pairs in contact of a dense packing (Z = 2 contacts / N about 5, README of the
    shared case: 4.9-5.3; bounds 4-6)."""
    out = tmp_path / "cps"
    run("compare_peers.py", "--no-peers", "--cases", "shear", "--shear-n", 8000, "--ranks", 1,
        "--repeats", 1, "--shear-warmup", 5, "--steps", 20, "--out", out)
    row, = load(f"{out}.json")["rows"]
    run_, = row["pardem"]
    assert (row["case"], row["n"], run_["elements"]) == ("shear", 8000, 8000)
    assert 4.0 < 2 * run_["contacts"] / 8000 < 6.0
    assert "| GRAN-SHEAR | 8000 | 1 | (not run) |" in (tmp_path / "cps.md").read_text()


@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_compare_peers_without_peers(tmp_path):
    out = tmp_path / "cp"
    run("compare_peers.py", "--no-peers", "--sizes", 6, "--ranks", 1, 2, "--repeats", 1, *SHORT,
        "--out", out)
    data = load(f"{out}.json")
    assert sorted((r["case"], r["n"], r["ranks"]) for r in data["rows"]) == [
        ("bond", 6, 1), ("bond", 6, 2), ("gran", 6, 1), ("gran", 6, 2)]
    for r in data["rows"]:
        run_, = r["pardem"]
        assert run_["elements"] == 6 ** 3 and run_["seconds"] > 0
    table = (tmp_path / "cp.md").read_text()
    for case in ("GRAN", "BOND"):
        for ranks in (1, 2):
            assert f"| {case} | 6 | {ranks} | (not run) |" in table


@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_profile_compress(tmp_path):
    out = tmp_path / "profile.json"
    run("profile_compress.py", "--ranks", 1, 2, "--steps", 20, "--warmup", 5, "--repeats", 1, "--out", out)
    results = load(out)["results"]
    assert [r["ranks"] for r in results] == [1, 2]
    for r in results:
        cases = r["cases"]
        # the job and the benchmarks run the same 21^3 lattice; only the job and bench_damped damp
        assert {c["elements"] for c in cases.values()} == {21 ** 3}
        assert {n: c["damped"] for n, c in cases.items()} == {
            "compress": True, "bench": False, "bench_damped": True, "compress_row_flush": True}
        assert 0.0 < cases["compress"]["damping_share_of_bond_loop"] < 1.0
