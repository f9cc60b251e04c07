"""The watchdog (issue 16, item 5): no rank waits for ever. Two ranks run a coupled loop (one
allreduce and one heartbeat per step, as ``Simulation.run``); one rank is stopped with SIGSTOP,
or leaves while the other waits: the job ends within the timeout plus a few seconds, with one
line naming the silent rank.
"""
import pathlib
import re
import subprocess
import time

from tests.test_signals import Job, rank_pids, survivors

ROOT = pathlib.Path(__file__).resolve().parents[1]
LOOP = str(ROOT / "tests" / "mpi" / "watchdog_loop.py")
TIMEOUT = 5.0
# the verdict comes at most one period (1 s) after the timeout, the abort after 1 s of grace
# (Communicator.abort); 15 s more leave room for a machine shared by other jobs
LATE = 15.0


def rank_pids_printed(job, timeout=60):
    """{rank: pid} from the loop's ``rank R pid P`` lines (waits until both ranks printed)."""
    ranks, deadline = {}, time.monotonic() + timeout
    while len(ranks) < 2 and time.monotonic() < deadline:
        # the two ranks print at once: mpiexec may join their lines ("rank 1 pid 11rank 0 pid 12")
        for r, pid in re.findall(r"rank (\d+) pid (\d+?)(?=rank|\s|$)", "".join(job.stdout)):
            ranks[int(r)] = int(pid)
        time.sleep(0.1)
    return ranks


def watchdog_lines(job):
    return [ln for ln in job.stderr.splitlines() if ln.startswith("pardem: error: watchdog:")]


def stop_rank_1(args, ready, limit):
    """Start the loop with ``args``, wait for its ``ready`` line, SIGSTOP rank 1 and wait for the
    job to end (``limit`` + LATE + 30 s at most). Returns (job, exit code, seconds from the stop to
    the end, {rank: pid}); the job is killed whatever happens."""
    job = Job([LOOP, *args])
    try:
        job.wait_for(ready, timeout=120)
        ranks = rank_pids_printed(job)
        assert sorted(ranks) == [0, 1] and sorted(ranks.values()) == sorted(rank_pids(job.p.pid))
        t0 = time.monotonic()
        subprocess.run(["kill", "-STOP", str(ranks[1])], check=True)
        code = job.finish(timeout=limit + LATE + 30)
        return job, code, time.monotonic() - t0, ranks
    finally:
        job.kill()


def test_a_stopped_rank_is_named_and_the_job_ends():
    job, code, elapsed, ranks = stop_rank_1([str(TIMEOUT), "600"], "running", TIMEOUT)
    assert code == 1, job.stderr
    assert TIMEOUT <= elapsed < TIMEOUT + LATE, elapsed
    (line,) = watchdog_lines(job)
    assert "rank 1 silent for" in line and "run.watchdog_seconds = 5" in line, job.stderr
    assert not survivors(list(ranks.values())), "a rank outlived the abort (the stopped one too)"


def test_a_rank_stopped_before_the_first_step_is_named_and_the_job_ends():
    """Rank 1 is stopped while it builds its case (no time step yet) and rank 0 waits for it: the
    job ends after the start-up limit (``STARTUP_SECONDS``, set to 6 s here) naming rank 1."""
    startup = 6.0
    job, code, elapsed, ranks = stop_rank_1([str(TIMEOUT), "600", "build=600", f"startup={startup}"], "building",
                                            startup)
    assert code == 1, job.stderr
    assert startup <= elapsed < startup + LATE, elapsed
    (line,) = watchdog_lines(job)
    assert "rank 1 silent for" in line and "before the first time step" in line, job.stderr
    assert not survivors(list(ranks.values()))


def test_a_long_build_is_left_alone():
    """Rank 1 builds for 3 start-up limits (2 s each) while rank 0 waits: it is alive (its
    watchdog ticks), so no verdict; then the loop runs and the job ends cleanly."""
    job = Job([LOOP, "1", "2", "build=6", "startup=2"])
    try:
        code = job.finish(timeout=120)
    finally:
        job.kill()
    assert code == 0, job.stderr
    assert not watchdog_lines(job), job.stderr


def test_ranks_waiting_on_a_finished_rank_are_aborted():
    """Rank 1 leaves its loop (a bug: the ranks disagree on the step count) while rank 0 waits in
    an allreduce: everyone is alive, nobody progresses."""
    job = Job([LOOP, str(TIMEOUT), "600", "finish-early"])
    try:
        job.wait_for("running", timeout=120)
        code = job.finish(timeout=TIMEOUT + LATE + 30)
    finally:
        job.kill()
    assert code == 1, job.stderr
    (line,) = watchdog_lines(job)
    assert "no progress on rank 0" in line and "finished: rank 1" in line, job.stderr


def test_a_healthy_run_is_left_alone_and_ends_cleanly():
    """A loop of 3 s with a 1 s limit: every rank beats, so no verdict; the watchdog's messages end
    without an MPI error at finalisation."""
    job = Job([LOOP, "1", "3"])
    try:
        code = job.finish(timeout=120)
    finally:
        job.kill()
    assert code == 0, job.stderr
    assert not watchdog_lines(job) and "Assertion" not in job.stderr, job.stderr
    # the two ranks print at once: mpiexec may join their lines ("rank 1 done after 9 stepsrank 0 ...")
    done = re.findall(r"rank (\d+) done after \d+ steps", "".join(job.stdout))
    assert sorted(done) == ["0", "1"], job.stdout
