"""Stop signals with real signals on 2 ranks (issue 16, item 4): SIGTERM or SIGINT to mpiexec stops
every rank at the same step boundary, with one line on rank 0 and exit code 128 + signal number;
an interrupted run writes its final checkpoint (which restarts) and a summary marked
``interrupted``; a signal before the first time step ends the run at once.

mpiexec.mpich (hydra) forwards SIGTERM, SIGINT and SIGUSR1 to every rank (checked by hand with a
script printing the signals it receives); the ranks run in their own process groups.
"""
import json
import os
import pathlib
import queue
import signal
import subprocess
import sys
import threading
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
MPIEXEC = "mpiexec.mpich"
# a small compression (10 elements per edge) that runs far longer than the test waits
SMALL = ["--set", "domain.radius=0.0005", "--set", "run.progress_seconds=0.5", "--set", "output.series_every=100",
         "--steps", "10000000"]
# from the signal to the end of every rank: at most check_every = 50 steps (a few ms each here)
# plus the final checkpoint of 1000 elements; 30 s leaves room for a machine shared by other jobs
STOP_SECONDS = 30.0


def _children(pid):
    """Pids whose parent is ``pid`` (a /proc scan)."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    stat = f.read()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry))
    return out


def rank_pids(mpiexec_pid):
    """The rank processes of an mpiexec.mpich job: the children of its hydra proxies."""
    return [r for proxy in _children(mpiexec_pid) for r in _children(proxy)]


def alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def survivors(pids, grace=5.0):
    """The pids still running ``grace`` seconds after mpiexec ended (its proxies deliver the
    final SIGKILL a moment after the launcher itself exits)."""
    end = time.monotonic() + grace
    while time.monotonic() < end and any(alive(p) for p in pids):
        time.sleep(0.1)
    return [p for p in pids if alive(p)]


class Job:
    """An mpiexec job whose stdout lines are read by a thread (so the test can wait for one)."""

    def __init__(self, args, ranks=2, launcher=(MPIEXEC,)):
        self.p = subprocess.Popen([*launcher, "-n", str(ranks), sys.executable, *args], cwd=ROOT,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines, self.stdout = queue.Queue(), []
        self.stderr = ""
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.p.stdout:
            self.stdout.append(line)
            self.lines.put(line)

    def wait_for(self, prefix, timeout=600):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=1.0)
            except queue.Empty:
                assert self.p.poll() is None, f"job ended early ({self.p.returncode}): {self.p.stderr.read()}"
                continue
            if line.startswith(prefix):
                return line
        raise AssertionError(f"no line starting with {prefix!r} in {timeout} s")

    def kill(self):
        """End the job and its ranks if still running (a failed test leaves nothing behind)."""
        if self.p.poll() is None:
            ranks = rank_pids(self.p.pid)
            self.p.kill()
            for r in ranks:
                try:
                    os.kill(r, signal.SIGKILL)
                except OSError:
                    pass
            self.p.wait()

    def finish(self, timeout):
        try:
            self.p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.p.kill()
            raise
        self.stderr = self.p.stderr.read()
        return self.p.returncode


def stop_run(tmp_path, signum, extra=()):
    """Start the small compression on 2 ranks, wait for its first progress line (the time loop
    runs), send ``signum`` to mpiexec, and return (job, seconds to the end, rank pids)."""
    out = tmp_path / "run"
    job = Job(["-m", "pardem.drivers.compress", *SMALL, "--out", str(out), *extra])
    try:
        job.wait_for("step ", timeout=300)
        ranks = rank_pids(job.p.pid)
        assert len(ranks) == 2, ranks
        t0 = time.monotonic()
        job.p.send_signal(signum)
        job.finish(timeout=120)
    finally:
        job.kill()
    return job, time.monotonic() - t0, ranks, out


def stop_lines(job):
    return [ln for ln in job.stderr.splitlines() if ln.startswith("pardem: stopped by")]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_to_mpiexec_stops_every_rank_at_one_step(tmp_path, signum):
    job, seconds, ranks, _ = stop_run(tmp_path, signum)
    assert job.p.returncode == 128 + signum, job.stderr
    assert seconds < STOP_SECONDS, seconds
    assert not survivors(ranks), "a rank outlived mpiexec"
    lines = stop_lines(job)
    name = signal.Signals(signum).name
    assert len(lines) == 1 and lines[0].startswith(f"pardem: stopped by {name} at step "), job.stderr
    assert "Traceback" not in job.stderr and "Exception ignored" not in job.stderr, job.stderr
    # every rank stopped at the same step: the step is a multiple of check_every (50), where the
    # ranks reduce their stop requests
    step = int(lines[0].split(" at step ")[1].split(";")[0])
    assert step > 0 and step % 50 == 0, lines[0]


def test_an_interrupted_run_leaves_a_final_checkpoint_that_restarts_and_a_marked_summary(tmp_path):
    job, _, _, out = stop_run(tmp_path, signal.SIGTERM)
    assert job.p.returncode == 143, job.stderr
    (line,) = stop_lines(job)
    step = int(line.split(" at step ")[1].split(";")[0])
    assert "final checkpoint " in line and "restart with --restart " in line, line
    ck = line.split("restart with --restart ")[1].strip()
    assert os.path.isfile(ck) and f"{step:010d}" in ck, (ck, os.listdir(out / "checkpoints"))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"]["signal"] in ("SIGTERM", 15), summary["interrupted"]
    assert summary["steps"] == step
    # the final checkpoint continues the run (2 more sampling periods)
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.compress", "--restart", ck,
                        "--steps", str(step + 100), "--quiet"], cwd=ROOT, capture_output=True, text=True,
                       timeout=600)
    assert p.returncode in (0, 5) and "Traceback" not in p.stderr, p.stderr


def test_no_final_checkpoint_when_at_stop_is_off(tmp_path):
    job, _, _, out = stop_run(tmp_path, signal.SIGTERM, extra=["--set", "checkpoint.at_stop=false"])
    assert job.p.returncode == 143, job.stderr
    (line,) = stop_lines(job)
    assert "final checkpoint" not in line.replace("no final checkpoint", ""), line
    assert not (out / "checkpoints").exists() or not os.listdir(out / "checkpoints")


def _handles(pid, signum):
    """The process has a handler for ``signum`` (SigCgt of /proc/<pid>/status)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            caught = next(int(ln.split()[1], 16) for ln in f if ln.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(caught >> (signum - 1) & 1)


def test_a_signal_while_building_the_case_ends_the_run_at_once(tmp_path):
    """A compact packing of ~19 000 elements takes tens of seconds to build: a SIGTERM once both
    ranks handle it (the driver's handlers are installed) ends the job promptly with one line,
    not after the build. The signal goes to both ranks, as Ctrl-C (the process group) and Slurm
    deliver it: sent to mpiexec.mpich this early, hydra twice dropped it (the job ran to its end
    with exit 0), which is MPICH's forwarding, not pardem's handling."""
    job = Job(["-m", "pardem.drivers.compress", "--set", "domain.kind=compact", "--set", "domain.radius=0.0002",
               "--out", str(tmp_path / "run"), "--quiet"])
    end = time.monotonic() + 120
    try:
        _wait_for_handlers(job, end)
        t0 = time.monotonic()
        for r in rank_pids(job.p.pid):
            os.kill(r, signal.SIGTERM)
        code = job.finish(timeout=120)
        elapsed = time.monotonic() - t0
    finally:
        job.kill()
    assert code == 143, (job.stderr, job.stdout)   # both: an exit 0 with no stderr was seen once
    # the packing's FIRE relaxation runs in chunks between which the handler runs: well under the
    # build time
    assert elapsed < 15.0
    assert not job.stdout, job.stdout        # the header comes after the build: never printed
    lines = stop_lines(job)
    assert lines == ["pardem: stopped by SIGTERM before the first time step; nothing to save"], job.stderr


def test_a_signal_to_one_other_rank_while_building_ends_the_job_from_that_rank(tmp_path):
    """SIGTERM to rank 1 alone while the case is built: rank 1 does not wait in its handler (rank
    0 may be inside a collective waiting for it), and ends the job ``FOLLOW_SECONDS`` later with a
    line naming itself, since rank 0 never heard of the signal."""
    from pardem.parallel.communicator import FOLLOW_SECONDS
    job = Job(["-m", "pardem.drivers.compress", "--set", "domain.kind=compact", "--set", "domain.radius=0.0002",
               "--out", str(tmp_path / "run"), "--quiet"])
    end = time.monotonic() + 120
    try:
        _wait_for_handlers(job, end)
        (rank_1,) = [r for r in rank_pids(job.p.pid) if _pmi_rank(r) == "1"]
        t0 = time.monotonic()
        os.kill(rank_1, signal.SIGTERM)
        code = job.finish(timeout=120)
        elapsed = time.monotonic() - t0
    finally:
        job.kill()
    assert code == 143, job.stderr
    # FOLLOW_SECONDS, then the abort; 10 s more for a machine shared by other jobs
    assert FOLLOW_SECONDS <= elapsed < FOLLOW_SECONDS + 10.0, elapsed
    lines = [ln for ln in job.stderr.splitlines() if ln.startswith("pardem: ")]
    assert lines == ["pardem: rank 1: stopped by SIGTERM before the first time step; nothing to save"], job.stderr


def _pmi_rank(pid):
    """The MPI rank of process ``pid`` (hydra sets ``PMI_RANK`` in each rank's environment); ""
    for a process that is not (yet) a rank or is gone."""
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            env = dict(item.split(b"=", 1) for item in f.read().split(b"\0") if b"=" in item)
    except OSError:
        return ""
    return env.get(b"PMI_RANK", b"").decode()


def _wait_for_handlers(job, end):
    while time.monotonic() < end:
        # a proxy's child between its fork and its exec is still a copy of the proxy: it has the
        # proxy's SIGTERM handler but not yet PMI_RANK (seen once: the test then ran on at once)
        ranks = [r for r in rank_pids(job.p.pid) if _pmi_rank(r)]
        if len(ranks) == 2 and all(_handles(r, signal.SIGTERM) for r in ranks):
            return
        assert job.p.poll() is None, job.p.stderr.read()
        time.sleep(0.1)
    raise AssertionError("the ranks never installed a SIGTERM handler")


def slurm_up():
    """A Slurm cluster answers and has a node up (``sinfo``): the srun tests need one."""
    import shutil
    if not (shutil.which("srun") and shutil.which("sinfo") and shutil.which("scancel")):
        return False
    try:
        p = subprocess.run(["sinfo", "-h", "-o", "%a %T"], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return p.returncode == 0 and any(ln.split()[:1] == ["up"] and not ln.split()[1].startswith(("down", "drain"))
                                     for ln in p.stdout.splitlines() if ln.split())


@pytest.mark.skipif(not slurm_up(), reason="no Slurm cluster here (sinfo finds no node up)")
@pytest.mark.parametrize("how", ["scancel", "scancel --signal=TERM", "scancel --signal=INT"])
def test_scancel_under_srun_stops_every_rank_with_a_final_checkpoint(tmp_path, how):
    """Under ``srun --mpi=pmi2`` (srun starts the ranks itself) Slurm delivers the signal to every
    task: ``scancel`` (what the wall-time limit does, SIGTERM then SIGKILL after KillWait),
    ``scancel --signal=...`` and ``#SBATCH --signal`` (a signal alone). The ranks stop at one
    step, write the final checkpoint and the summary, and exit 128 + N themselves (no MPI_Abort,
    which srun would report as "Killed", 137), before KillWait's SIGKILL."""
    name = f"pardem-test-{os.getpid()}-{tmp_path.name}"[:60]
    out = tmp_path / "run"
    job = Job(["-m", "pardem.drivers.compress", *SMALL, "--out", str(out)],
              launcher=("srun", "--mpi=pmi2", f"--job-name={name}", "--time=10"))
    try:
        job.wait_for("step ", timeout=300)
        t0 = time.monotonic()
        subprocess.run([*how.split(), f"--name={name}"], check=True, timeout=60)
        job.finish(timeout=120)
        seconds = time.monotonic() - t0
    finally:
        if job.p.poll() is None:
            subprocess.run(["scancel", "--signal=KILL", f"--name={name}"], timeout=60)
        job.kill()
    signum = signal.SIGINT if how.endswith("INT") else signal.SIGTERM
    assert job.p.returncode == 128 + signum, job.stderr
    # Slurm's KillWait (30 s by default) would end the tasks with SIGKILL (137) after that
    assert seconds < STOP_SECONDS, seconds
    (line,) = stop_lines(job)
    assert line.startswith(f"pardem: stopped by {signal.Signals(signum).name} at step "), line
    assert "Traceback" not in job.stderr and "Killed" not in job.stderr, job.stderr
    step = int(line.split(" at step ")[1].split(";")[0])
    assert step > 0 and step % 50 == 0, line
    ck = line.split("restart with --restart ")[1].strip()
    assert os.path.isfile(ck) and f"{step:010d}" in ck, ck
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"]["signal"] in (signal.Signals(signum).name, int(signum)), summary
