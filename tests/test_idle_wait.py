"""``Communicator.wait_for_all``: a rank that finished its share of a task farm waits for the others
without using a core, returns only once every rank arrived, and a rank failing meanwhile still ends
the job (run as ``mpiexec -n 2`` subprocesses)."""
import json
import os
import shutil
import subprocess
import sys
import textwrap
import time

import pytest

from pardem.parallel.communicator import Communicator

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LATE_SECONDS = 2.0      # how long rank 0 keeps rank 1 waiting

IDLE = textwrap.dedent(f"""
    import json, pathlib, sys, time
    from pardem.parallel.communicator import Communicator
    comm = Communicator()
    comm.barrier()                       # both ranks started: the wait below is rank 0's delay only
    if comm.rank == 0:
        time.sleep({LATE_SECONDS})
    wall, cpu = time.perf_counter(), time.process_time()
    comm.wait_for_all()
    took = {{"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu}}
    # one file per rank: mpiexec may join the two ranks' stdout lines
    pathlib.Path(sys.argv[1], f"rank{{comm.rank}}.json").write_text(json.dumps(took))
""")

# rank 0's realisation fails 1.5 s into the farm, while rank 1 (its realisation done) waits; the
# driver's failure policy (cli.run_driver) must end both ranks
FAILING_FARM = textwrap.dedent("""
    import sys, time
    from types import SimpleNamespace
    from pardem.drivers.cli import run_driver
    from pardem.parallel.communicator import Communicator
    from pardem.protocols import compact_calibration as cc

    def measure(comm, deck, plan, seed, young, radius_ratio, packings):
        if seed == 0:
            time.sleep(1.5)
            raise RuntimeError("injected failure of realisation 0")
        print("rank 1 measured", flush=True)
        return {}

    def run(comm, args):
        cc.measure_realisation = measure
        cc.farm_measure(comm, None, SimpleNamespace(seeds=[0, 1]), 1e9, 0.5, None)
        print(f"rank {comm.rank} returned", flush=True)
        return 0

    comm = Communicator()
    sys.exit(run_driver(comm, run, None))
""")


@pytest.mark.mpi
def test_an_early_rank_sleeps_until_the_late_one_arrives(tmp_path):
    script = tmp_path / "idle.py"
    script.write_text(IDLE)
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, str(script), str(tmp_path)], capture_output=True,
                       text=True, timeout=120, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    ranks = {k: json.loads((tmp_path / f"rank{k}.json").read_text()) for k in (0, 1)}   # both returned
    # rank 1 returned only after rank 0 arrived (2 s; 0.5 s of slack for the start-up barrier's skew)
    assert ranks[1]["wall"] >= LATE_SECONDS - 0.5, ranks
    # a busy poll (MPICH's blocking Barrier or Gather) uses about the whole 2 s of CPU; sleeping
    # 50 ms between Test polls uses milliseconds. 0.5 s leaves room for a loaded machine's
    # scheduling noise and MPICH/UCX progress threads, and still fails a poll spinning a quarter of the time
    assert ranks[1]["cpu"] < 0.5, ranks


def test_one_rank_returns_at_once():
    comm = Communicator()
    assert comm.size == 1
    start = time.perf_counter()
    comm.wait_for_all(poll_seconds=60.0)
    # one sleep between polls would take 60 s; 5 s is far from both that and the call's microseconds
    assert time.perf_counter() - start < 5.0


@pytest.mark.mpi
def test_a_rank_failing_while_another_waits_ends_the_job(tmp_path):
    script = tmp_path / "failing_farm.py"
    script.write_text(FAILING_FARM)
    start = time.perf_counter()
    # the timeout is the hang detector: the abort ends the job about 3 s in (1.5 s of work, 1 s
    # ABORT_GRACE_SECONDS, start-up); a waiting rank that survived the abort would run into it
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, str(script)], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert p.returncode != 0, (p.stdout, p.stderr)
    assert "rank 0: unexpected error" in p.stderr and "injected failure of realisation 0" in p.stderr, p.stderr
    assert "rank 1 measured" in p.stdout, p.stdout    # rank 1 was done and waiting when rank 0 failed
    assert "returned" not in p.stdout, p.stdout       # neither rank got past the farm
    assert time.perf_counter() - start < 60.0, "the waiting rank outlived the abort"
