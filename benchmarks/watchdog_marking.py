"""What the script watchdog costs the time loop: the marking of every blocking ``Communicator``
call (``pardem.parallel.watchdog.COLLECTIVE``) and the watchdog thread's stack sample.

    python benchmarks/watchdog_marking.py                 # the per-call costs (one process)
    mpiexec -n 2 python benchmarks/watchdog_marking.py --steps 2000 --n 20

One process: the time of a call of a no-op C function bare, wrapped in the inline marking
(``Communicator._allreduce``, ``waitall``) and through ``Communicator._collective`` (the pickled
verbs, ``barrier``), best of 5 rounds of 10^6 calls; and the watchdog thread's work per round
(``Watchdog._mine``: the stack sample and the slot). On 2 ranks: a GRAN box of n^3 spheres
(``benchmarks/bench_gran.py``'s case, Hertz-Mindlin) runs STEPS steps; the marked calls per step
(from ``COLLECTIVE.calls``) times the inline marking's cost, against the wall time of a step, bound
the marking's share of the step.
"""
import argparse
import time
import timeit

import numpy as np

from pardem.parallel import watchdog
from pardem.parallel.communicator import Communicator


def per_call():
    at, noop = watchdog.COLLECTIVE, len     # a C function, as the mpi4py calls are
    comm = Communicator()

    def bare():
        noop(())

    def inline():
        at.name = "Communicator.sum"
        at.calls += 1
        try:
            noop(())
        finally:
            at.calls += 1

    def helper():
        comm._collective("Communicator.barrier", noop, ())

    n = 10**6
    best = {f.__name__: min(timeit.repeat(f, number=n, repeat=5)) / n for f in (bare, inline, helper)}
    at.calls = 0
    return {"inline marking [ns]": 1e9 * (best["inline"] - best["bare"]),
            "_collective helper [ns]": 1e9 * (best["helper"] - best["bare"])}


def thread_round():
    """Seconds of ``Watchdog._mine`` (one per watchdog round) from a depth of a few frames."""
    class Fake:
        _ticks, _finished, _main = 0, False, None
        _sbuf = np.zeros((1, watchdog._HEAD + watchdog.WHERE_BYTES // 8))
    import threading
    Fake._main = threading.main_thread().ident
    f = Fake()
    n = 2000
    return min(timeit.repeat(lambda: watchdog.Watchdog._mine(f), number=n, repeat=5)) / n


def gran(n, steps):
    from pardem.engine import granular
    from pardem.engine.system import Cell, ContactModel, Decomposition, Integration, Particles, System, build
    R, params = 0.1e-3, {"young": 72e9, "poisson": 0.2, "friction": 0.5}     # bench_gran.py's case
    comm = Communicator()
    pos, side = granular.simple_cubic(n, R, spacing=1.998, jitter=0.0002, seed=12345)
    sim = build(comm, System(Particles(pos, R, 2500.0), contacts=ContactModel("hertz_mindlin", params),
                             cell=Cell(np.zeros(3), np.full(3, side)), integration=Integration(dt=1e-8),
                             decomposition=Decomposition(slab_axis=0, skin=0.1 * R)))
    sim.run(100)
    comm.barrier()
    calls0, t0 = watchdog.COLLECTIVE.calls, time.perf_counter()
    sim.run(steps)
    wall = time.perf_counter() - t0
    marked = (watchdog.COLLECTIVE.calls - calls0) / 2 / steps
    return comm, wall / steps, marked


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=0, help="GRAN steps on the ranks (0: per-call costs only)")
    ap.add_argument("--n", type=int, default=20, help="spheres per edge of the GRAN box")
    args = ap.parse_args()
    costs = per_call()
    lines = [f"{k}: {v:.0f}" for k, v in costs.items()]
    lines.append(f"watchdog round (stack sample and slot) [us]: {1e6 * thread_round():.1f}")
    if args.steps:
        comm, step, marked = gran(args.n, args.steps)
        share = marked * costs["_collective helper [ns]"] * 1e-9 / step
        lines.append(f"GRAN n = {args.n} on {comm.size} rank(s): {1e6 * step:.1f} us a step, {marked:.3f} marked "
                     f"calls a step, marking < {100 * share:.4f} % of a step (at the helper's cost)")
        if not comm.is_root:
            return
    print("\n".join(lines))


if __name__ == "__main__":
    main()
