"""Insertion and deletion during a run on any number of ranks (tests/test_insertion.py).

    python insertion_run.py OUT_DIR        (or under mpiexec -n 2)

A bed of grains in a box of walls under gravity; an ``Insert`` pours batches of log-normal grains
from a cylinder above it and a ``Delete`` removes the grains above a height; then a checkpoint,
more steps with insertions, and the same steps from the checkpoint read back. Writes
``OUT_DIR/insertion.npz`` from rank 0: the final arrays of both (``restarted_*``), the counters and
how many ranks owned grains. Every rank checks that it read the same bits as the others.
"""
import sys

import numpy as np

import pardem
from pardem.domains import distributions as D
from pardem.domains import regions as R
from pardem.domains.packing import random_pack
from pardem.engine.insertion import Delete, Insert

out_dir = sys.argv[1]
comm = pardem.Communicator()
RAD, W = 1e-3, 0.02
cloud = random_pack(R.Box([0, 0, 0], [W, W, 0.012]), D.Uniform(0.8 * RAD, 1.2 * RAD), n=150, seed=1)
walls = pardem.WallModel(normals=[[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]],
                         points=[[0, 0, 0], [0, 0, 0], [W, 0, 0], [0, 0, 0], [0, W, 0]],
                         law=pardem.wall_law("hertz", young=1e7, poisson=0.3, restitution=0.3, friction=0.3))
system = pardem.System(pardem.Particles(cloud.positions, cloud.radii, 2500.0),
                       contacts=pardem.ContactModel("hertz_mindlin", dict(young=1e7, poisson=0.3, friction=0.5,
                                                                             restitution=0.3)),
                       walls=walls, integration=pardem.Integration(orientation=False),
                       decomposition=pardem.Decomposition(slab_axis=0))
sim = pardem.build(comm, system)
pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -9.81)))
sim.particles.add_property("tag", default=1.0)
source = R.Cylinder([0.01, 0.01, 0.02], 0.008, 0.01)
dist = D.LogNormal(RAD, 0.15)


def operations():
    return [Insert(source, dist, trigger=150, n=25, seed=4, velocity=(0.0, 0.0, -0.2)),
            Delete(trigger=100, outside=R.Box([-1, -1, -1], [1, 1, 0.028]))]


ops = operations()
sim.run(600, operations=ops)
inserted, deleted = ops[0].inserted, ops[1].deleted
path = f"{out_dir}/poured.h5"
pardem.save(sim, path)
sim.run(450, operations=operations())
back = pardem.load(comm, path)
# the restored forces hold gravity already: appended, not add_fixes (which applies a fix added
# after a run to the current forces, so gravity twice in the first half kick)
back.fixes.append(pardem.Gravity((0.0, 0.0, -9.81)))
back.run(450, operations=operations())

out = {"ranks": comm.size, "inserted": inserted, "deleted": deleted,
       "owners": int(comm.sum(float(sim.elements.n_owned > 0)))}
for tag, s in (("", sim), ("restarted_", back)):
    for k in ("positions", "velocities", "gids", "radii", "tag"):
        a = s.particles.get(k)
        got = comm.allgather(a.tobytes())
        assert all(g == got[0] for g in got), f"{k}: the ranks read different values"
        out[tag + k] = a
    out[tag + "kinetic"] = s.kinetic_energy()
if comm.is_root:
    np.savez(f"{out_dir}/insertion.npz", **out)
