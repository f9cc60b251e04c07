"""Run under mpiexec: a periodic cluster of frictional grains with a ``ContactWriter``.

Usage: ``mpiexec -n K python contact_writer_run.py OUTDIR``. Writes ``OUTDIR/contacts.h5`` (the
writer, steps ``EVERY, 2 EVERY, ...``), ``OUTDIR/pv`` (ParaView at the same steps) and ``OUTDIR/state-rRRRR.npz`` (each rank: gid, contact
force f [N] and torque t [N m] of its owned grains after the last step, the writer's last group).
"""
import os
import sys

import numpy as np

import pardem
from pardem.io.contact_writer import ContactWriter
from pardem.io.paraview import ParaViewWriter

STEPS, EVERY = 40, 20


def system():
    """6 x 4 x 4 grains of radius ~1 mm on a jittered lattice of spacing 1.9 mm (many overlaps),
    periodic, moving and spinning: sliding and sticking contacts, some across the boundaries."""
    rng = np.random.default_rng(5)
    shape = np.array([6, 4, 4])
    a = 1.9e-3
    g = [np.arange(k) * a for k in shape]
    x = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3) + 0.5 * a
    x += rng.uniform(-1.5e-4, 1.5e-4, x.shape)
    r = rng.uniform(0.95e-3, 1.05e-3, len(x))
    v = rng.normal(size=x.shape) * 0.2
    w = rng.normal(size=x.shape) * 300.0
    return pardem.System(pardem.Particles(x, r, 2500.0, v, w),
                         contacts=pardem.ContactModel("hertz_mindlin", {"young": 1e8, "poisson": 0.3,
                                                                        "friction": 0.3}),
                         cell=pardem.Cell(lo=(0.0, 0.0, 0.0), length=tuple(shape * a)),
                         integration=pardem.Integration(dt=5e-7),
                         decomposition=pardem.Decomposition(slab_axis=0))


if __name__ == "__main__":
    out = sys.argv[1]
    comm = pardem.Communicator()
    sim = pardem.build(comm, system())
    sim.run(STEPS, operations=[ContactWriter(os.path.join(out, "contacts.h5"), trigger=EVERY),
                               ParaViewWriter(os.path.join(out, "pv"), comm, EVERY)])
    e = sim.elements
    n = e.n_owned
    np.savez(os.path.join(out, f"state-r{comm.rank:04d}.npz"), gid=e.gid[:n], f=e.f[:n], t=e.t[:n])
