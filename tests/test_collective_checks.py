"""Input checks give one verdict on every rank (issue 16, items 5 and 6): a problem that only one
rank sees (its environment, its node's free memory, its view of a file) ends the whole job with
one line and exit 2 before any output, instead of leaving the other ranks to wait for it in the
build. Each rank's environment is set apart with mpiexec's MPMD form (``-n 1 ... : -n 1 -env ...``).
"""
import os
import shutil
import subprocess
import sys

import pytest

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def mpmd(out, bad_env, driver="compress", timeout=240):
    """Rank 0 with a clean environment, rank 1 with ``bad_env`` ({name: value})."""
    cmd = [sys.executable, "-m", f"pardem.drivers.{driver}", "--quiet", "--out", str(out), "--steps", "10"]
    env_args = [a for k, v in bad_env.items() for a in ("-env", k, v)]
    p = subprocess.run([MPIEXEC, "-n", "1", *cmd, ":", "-n", "1", *env_args, *cmd],
                       capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    return p


@pytest.mark.mpi
@pytest.mark.parametrize("driver", ["compress", "isotropic"])
def test_a_problem_seen_by_one_rank_ends_every_rank_with_one_line(tmp_path, driver):
    """Before: rank 1 exited 2 and rank 0 went on into the build and waited for it (a hang until
    the watchdog). The timeout of the run (240 s) is the hang detector; the job ends in seconds."""
    out = tmp_path / "run"
    p = mpmd(out, {"PARDEM_CHECKPOINT_PAUSE": "soon"}, driver)
    assert p.returncode == 2, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("pardem: error:")]
    assert lines == ["pardem: error: rank 1: PARDEM_CHECKPOINT_PAUSE = 'soon': expected seconds, a "
                     "number in [0, 3600]"], p.stderr
    assert "Traceback" not in p.stderr
    assert not out.exists()          # refused before any output was created


@pytest.mark.mpi
def test_the_same_problem_on_every_rank_is_reported_once_without_a_rank(tmp_path):
    out = tmp_path / "run"
    cmd = [MPIEXEC, "-n", "2", "-env", "PARDEM_CHECKPOINT_PAUSE", "-1", sys.executable, "-m",
           "pardem.drivers.compress", "--quiet", "--out", str(out)]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert p.returncode == 2, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("pardem: error:")]
    assert lines == ["pardem: error: PARDEM_CHECKPOINT_PAUSE = '-1': expected seconds, a number in [0, 3600]"]
    assert not out.exists()


def test_the_memory_check_counts_every_rank_on_the_node(monkeypatch):
    """Every rank on a node builds the whole case before keeping its slab: a deck whose one build
    fits the node's free memory but two do not is refused on 2 ranks per node, not on 1."""
    from pardem.config import DeckError
    from pardem.protocols import deck_checks as dc
    n = 1e6
    need = dc.estimate_memory(n, 3 * n, 0.0)
    monkeypatch.setattr(dc, "available_memory", lambda: 1.5 * need)
    try:
        dc.set_ranks_per_node(1)
        assert dc.check_memory(n, 3 * n, 0.0, "domain.box", "1e6 elements") == need
        dc.set_ranks_per_node(2)
        with pytest.raises(DeckError, match=r"2 ranks on this node each build the whole case"):
            dc.check_memory(n, 3 * n, 0.0, "domain.box", "1e6 elements")
    finally:
        dc.set_ranks_per_node(1)


@pytest.mark.mpi
def test_ranks_on_node_counts_the_ranks_sharing_this_machine():
    code = ("from pardem.parallel.communicator import Communicator; from pardem.parallel import layout; "
            "c = Communicator(); n = layout.ranks_on_node(c); print('node', n) if c.is_root else None")
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["node", "2"]      # both ranks run on this one machine
