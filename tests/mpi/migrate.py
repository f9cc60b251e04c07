"""Run under mpiexec: a bonded lattice translated bodily across several slab boundaries.

Writes JSON (rank 0) with what the test checks: every element and bond present exactly once, with
its data unchanged (bond state, orientation, velocity) and its position moved by v t.
"""
import json
import sys

import numpy as np

from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.domains.ordered import ordered_lattice
from pardem.parallel.communicator import Communicator
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import Slabs
from pardem.physics.quaternion import quat_from_rotvec
from pardem.engine.simulation import Simulation
from pardem.engine.state import BOND_FIELDS, Elements, Plates

out_path = sys.argv[1]
comm = Communicator()
R = 0.25e-3
# 24 x 4 x 4 elements along x; slabs along x, cut at fixed places (no rebalancing)
pos, pairs, frame = ordered_lattice([24 * 2 * R, 8 * R, 8 * R], R)
rng = np.random.default_rng(7)
full = Elements.from_spheres(pos, R, 1000.0)
for k in range(len(pos)):                 # non-trivial orientations: body-frame bond vectors differ
    full.q[k] = quat_from_rotvec(rng.normal(size=3))
full.refresh_rotations()
bonds_full = make_bonds(full, pairs, BeamMaterial(1e8, 1.0, 0.3, 0.2), frame)
V = 40.0                                     # m/s along x
full.v[:, 0] = V
DT, STEPS = 1e-7, 4500                       # travel 18 mm: 1.5 times the lattice length
L = 48 * R
# cuts spread over the whole path [0, 2L]; rank 0 starts with every element and bond, so the
# first exchange already moves elements over several slabs, then the motion carries them on
cuts = np.linspace(0.0, 2 * L, comm.size + 1)[1:-1]
slabs = Slabs(0, cuts, np.zeros(comm.size - 1, dtype=np.int64))
none = np.zeros(0, dtype=np.int64)
if comm.rank == 0:
    start, b0 = Elements.unpack([full.pack(slice(None))], len(pos)), bonds_full
else:
    start = Elements.unpack([full.pack(none)], 0)
    b0 = type(bonds_full).unpack([bonds_full.pack(none)], True)
domain = SlabComm(comm, slabs, ghost_range=1.25 * 2 * R + 0.1 * R, skin=0.1 * R, balance_every=0)
e, b = domain.setup(start, b0)
plates = Plates.pair(0, -1.0, 1.0, 0.0, 1.0)
sim = Simulation(comm, e, b, plates, dt=DT, domain=domain)
sim.run(STEPS)

e, b = sim.elements, sim.bonds
n = e.n_owned
owned = comm.comm.gather({"gid": e.gid[:n], "x": e.x[:n], "v": e.v[:n], "q": e.q[:n], "w": e.w[:n]}, root=0)
held = comm.comm.gather(b.pack(slice(None)), root=0)
counts = comm.comm.gather(int(n), root=0)
if comm.rank == 0:
    gids = np.concatenate([o["gid"] for o in owned])
    x = np.concatenate([o["x"] for o in owned])[np.argsort(gids)]
    v = np.concatenate([o["v"] for o in owned])[np.argsort(gids)]
    q = np.concatenate([o["q"] for o in owned])[np.argsort(gids)]
    w = np.concatenate([o["w"] for o in owned])[np.argsort(gids)]
    bg = np.concatenate([h["gid"] for h in held])
    ref = bonds_full.pack(slice(None))
    altered = []
    for k in BOND_FIELDS:
        got = {}
        for h in held:
            for g, val in zip(h["gid"], h[k]):
                if g in got and not np.array_equal(got[g], val):
                    altered.append(f"{k} of bond {g} differs between ranks")
                got[g] = val
        refd = dict(zip(ref["gid"], ref[k]))
        altered += [f"{k} of bond {g}" for g in got if not np.array_equal(got[g], refd[g])]
    t = STEPS * DT
    result = {
        "n_elements": len(pos), "n_bonds": bonds_full.n, "owned_counts": counts,
        "unique_elements": int(len(np.unique(gids))), "total_owned": int(len(gids)),
        "unique_bonds_held": int(len(np.unique(bg))),
        "missing_bonds": int(len(np.setdiff1d(bonds_full.gid, bg))),
        "altered": altered[:10],
        "x_error": float(np.abs(x - (pos + [V * t, 0, 0])).max() / (V * t)),
        "v_error": float(np.abs(v - [V, 0, 0]).max() / V),
        "q_error": float(np.abs(q - full.q).max()),
        "w_max": float(np.abs(w).max()),
        "rebuilds": domain.rebuilds, "travel_in_slab_widths": V * t / (2 * L / comm.size),
    }
    with open(out_path, "w") as fh:
        json.dump(result, fh)
