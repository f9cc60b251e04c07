"""A user's script under ``mpiexec -n 2`` that does nothing about the watchdog: the first
``Communicator`` starts it (``pardem.parallel.watchdog.protect_script``, limit from
``PARDEM_WATCHDOG_SECONDS``). Builds a small granular box, runs STEPS steps, then:

    mpiexec -n 2 python tests/mpi/script_hang.py MODE STEPS

``ok``: every rank asks for the kinetic energy (the correct script), then leaves;
``hang``: only rank 0 asks for it (a collective inside ``if comm.rank == 0``) while rank 1 works
outside any collective (a sleep of 600 s);
``barrier``: only rank 0 asks for it while rank 1 waits in a barrier (different collectives);
``leave``: only rank 0 asks for it while rank 1 reaches the end of the script;
``idle``: rank 0 works for 2.5 limits while rank 1 waits in ``wait_for_all`` (a task farm's rank
done early: a legitimate wait), then every rank asks for the energy.
The lines the tests look for end with the markers ``# <- the call`` and ``# <- rank 1 ...``.
"""
import sys
import time

import numpy as np

import pardem
from pardem.parallel import watchdog


def main():
    mode, steps = sys.argv[1], int(sys.argv[2])
    comm = pardem.Communicator()
    # 4 x 4 x 4 spheres of radius 1 mm, 2.5 mm apart, in a periodic box, moving at random
    R, n = 1e-3, 4
    grid = (np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) * 2.5 * R
    v = np.random.default_rng(1).normal(0.0, 0.05, grid.shape)
    law = pardem.ContactModel("linear", {"kn": 1e4, "kt": 1e4, "friction": 0.3, "restitution": 0.8})
    sim = pardem.build(comm, pardem.System(pardem.Particles(grid, R, 2500.0, velocities=v), contacts=law,
                                           cell=pardem.Cell([0.0, 0.0, 0.0], [n * 2.5 * R] * 3),
                                           integration=pardem.Integration(dt_fraction=0.2)))
    sim.run(steps)
    if comm.is_root:
        print(f"ran {sim.step_count} steps", flush=True)
    if mode == "idle":
        if comm.rank == 0:
            time.sleep(2.5 * watchdog.script_seconds())
        comm.wait_for_all()
    if mode in ("ok", "idle"):
        energy = sim.kinetic_energy()
    elif comm.rank == 0:
        energy = sim.kinetic_energy()   # <- the call
    elif mode == "hang":
        time.sleep(600.0)   # <- rank 1 works
    elif mode == "barrier":
        comm.barrier()   # <- rank 1 waits
    if comm.is_root:
        print(f"kinetic energy {energy:.6e} J", flush=True)


if __name__ == "__main__":
    main()
