"""The script watchdog: a user's script under ``mpiexec -n 2`` that calls a collective on one rank
only (``sim.kinetic_energy()`` inside ``if comm.rank == 0``) ends within the limit with one line
naming the collective, its callers and what the other rank does; the same script written correctly
runs to its end untouched, also for thousands of steps with a limit of a few seconds
(``tests/mpi/script_hang.py``; the limit from ``PARDEM_WATCHDOG_SECONDS``).
"""
import pathlib
import re
import threading
import time

import pytest

from pardem.parallel import watchdog
from pardem.parallel.communicator import Communicator
from tests.test_signals import Job

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tests" / "mpi" / "script_hang.py"
SHOWN = "tests/mpi/script_hang.py"   # the script's path in the line (relative to the ranks' cwd, ROOT)
LIMIT = 4.0
# the verdict comes at most two rounds (0.4 s each at this limit) after the limit, seen from the
# rank that reports, then 1 s of grace (Communicator.abort); 15 s more leave room for a machine
# shared by other jobs
LATE = 15.0


def marked(marker):
    """The line number of the script's line carrying ``marker``."""
    (n,) = [i for i, line in enumerate(SCRIPT.read_text().splitlines(), 1) if line.endswith(marker)]
    return n


def run(mode, steps, monkeypatch, seconds=LIMIT, wait=None):
    """Run the script on 2 ranks; returns (exit code or None if still running after ``wait`` s,
    seconds from rank 0's ``ran`` line to the end, the watchdog's lines, the job)."""
    monkeypatch.setenv(watchdog.ENV, str(seconds))
    job = Job([str(SCRIPT), mode, str(steps)])
    try:
        job.wait_for("ran ", timeout=300)
        t0 = time.monotonic()
        if wait is not None:
            try:
                job.p.wait(timeout=wait)
            except Exception:        # noqa: BLE001 - still running: what the caller checks
                return None, time.monotonic() - t0, [], job
        code = job.finish(timeout=seconds + LATE + 30)
        lines = [ln for ln in job.stderr.splitlines() if ln.startswith("pardem: error: watchdog:")]
        return code, time.monotonic() - t0, lines, job
    finally:
        job.kill()


def test_a_collective_called_on_one_rank_ends_the_job_naming_it_and_both_ranks(monkeypatch):
    code, elapsed, lines, job = run("hang", 200, monkeypatch)
    assert code == 1, job.stderr
    assert LIMIT <= elapsed < LIMIT + LATE, elapsed
    (line,) = lines
    call, other = marked("# <- the call"), marked("# <- rank 1 works")
    assert re.search(r"rank 0 has waited \d+ s in Communicator\.sum called from pardem/\S+ \(\S+\) <- "
                     r"pardem/engine/simulation\.py:\d+ \(Simulation\.kinetic_energy\) <- "
                     + re.escape(f"{SHOWN}:{call};"), line), line
    assert f"rank 1 is outside any collective, at {SHOWN}:{other} " in line, line
    assert "a collective called on some ranks only" in line and "limit 4 s" in line and watchdog.ENV in line, line


def test_ranks_in_different_collectives_are_named_with_theirs(monkeypatch):
    code, elapsed, lines, job = run("barrier", 200, monkeypatch)
    assert code == 1, job.stderr
    assert LIMIT <= elapsed < LIMIT + LATE, elapsed
    (line,) = lines
    assert f"{SHOWN}:{marked('# <- the call')};" in line, line
    assert "rank 1 has waited" in line and f"in Communicator.barrier called from {SHOWN}:{marked('# <- rank 1 waits')} " in line, line
    assert "the ranks are in different collectives" in line, line


def test_a_rank_that_left_the_script_is_named(monkeypatch):
    code, elapsed, lines, job = run("leave", 200, monkeypatch)
    assert code == 1, job.stderr
    assert LIMIT <= elapsed < LIMIT + LATE, elapsed
    (line,) = lines
    assert "rank 0 has waited" in line and "rank 1 has left the script" in line, line


def test_the_correct_script_runs_thousands_of_steps_and_ends_cleanly(monkeypatch):
    """Every step marks the halo exchange's ``waitall`` and every 50th a reduction; a limit of 3 s is
    far below the run's length, yet no call stays open that long."""
    code, elapsed, lines, job = run("ok", 5000, monkeypatch, seconds=3.0)
    assert code == 0, job.stderr
    assert not lines and "Assertion" not in job.stderr, job.stderr
    assert "kinetic energy" in "".join(job.stdout)


def test_a_long_wait_for_all_is_left_alone(monkeypatch):
    """``wait_for_all`` is where a task farm's rank done early waits, however long: rank 1 waits
    there for 2.5 limits while rank 0 works, and the script ends normally."""
    code, elapsed, lines, job = run("idle", 10, monkeypatch)
    assert code == 0, job.stderr
    assert elapsed >= 2.5 * LIMIT, elapsed
    assert not lines, job.stderr


def test_a_limit_of_0_switches_the_script_watchdog_off(monkeypatch):
    """With ``PARDEM_WATCHDOG_SECONDS=0`` the hang is left alone: still running at 3 times the
    default test limit (the test then ends it)."""
    code, elapsed, lines, job = run("hang", 10, monkeypatch, seconds=0, wait=3 * LIMIT)
    assert code is None, job.stderr


def test_one_rank_starts_nothing():
    comm = Communicator()
    assert comm.size == 1
    comm.sum(1.0)
    assert watchdog._current is None
    assert "pardem-watchdog" not in [t.name for t in threading.enumerate()]


@pytest.mark.parametrize("text", ["abc", "-1", "nan", "inf"])
def test_a_bad_limit_in_the_environment_is_one_clear_error(monkeypatch, text):
    monkeypatch.setattr(watchdog, "_script_seconds", None)   # a limit set by an earlier test's configure()
    monkeypatch.setenv(watchdog.ENV, text)
    with pytest.raises(ValueError, match=f"{watchdog.ENV}=.*expected a number of seconds >= 0"):
        watchdog.script_seconds()
