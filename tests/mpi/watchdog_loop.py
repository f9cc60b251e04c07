"""A coupled loop for the watchdog tests: every 'step' is one allreduce over the ranks and one
``watchdog.beat()``, like ``Simulation.run``. Prints ``rank R pid P`` and then ``running`` once
(rank 0) so the test knows the loop is armed.

    mpiexec -n 2 python tests/mpi/watchdog_loop.py TIMEOUT SECONDS [finish-early]

``finish-early``: rank 1 leaves after 1 s (stops its watchdog) while rank 0 waits in an allreduce
for ever: the deadlock case. ``build=B``: before the loop, rank 1 "builds the case" for B seconds
(no step, its watchdog thread alive) while rank 0 waits for it in an allreduce; prints
``building``. ``startup=S`` sets ``watchdog.STARTUP_SECONDS``.
"""
import os
import sys
import time

from pardem.parallel import watchdog
from pardem.parallel.communicator import Communicator


def main():
    timeout, seconds = float(sys.argv[1]), float(sys.argv[2])
    finish_early = "finish-early" in sys.argv[3:]
    opts = dict(a.split("=") for a in sys.argv[3:] if "=" in a)
    if "startup" in opts:
        watchdog.STARTUP_SECONDS = float(opts["startup"])
    comm = Communicator()
    watchdog.start(comm, timeout)
    print(f"rank {comm.rank} pid {os.getpid()}", flush=True)
    if "build" in opts:
        if comm.is_root:
            print("building", flush=True)
        if comm.rank == 1:
            time.sleep(float(opts["build"]))
        comm.sum(1.0)
    t0, step = time.monotonic(), 0
    while True:
        comm.sum(1.0)          # every rank waits for all the others here
        watchdog.beat()
        step += 1
        if step == 20 and comm.is_root:
            print("running", flush=True)
        if finish_early and comm.rank == 1 and time.monotonic() - t0 > 1.0:
            break
        # the same number of steps on every rank: rank 0 decides when to stop
        if comm.bcast(time.monotonic() - t0 > seconds if comm.is_root else None):
            break
        time.sleep(0.01)
    watchdog.pause()
    watchdog.stop()
    print(f"rank {comm.rank} done after {step} steps", flush=True)


if __name__ == "__main__":
    main()
