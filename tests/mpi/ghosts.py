"""Run under mpiexec: in every step, every ghost row equals its owner's row bit for bit, and every
element within interaction range of an owned row is held (brute force over all pairs).

The check runs right after the slab layer's update (migration + ghosts, or the ghost refresh),
i.e. on exactly the state the force kernels then use (velocities at the half step).

A compression with slabs along the loading axis (so elements migrate) and a small skin (so ghosts
are rebuilt often). Writes JSON (rank 0): steps checked, rebuilds, mismatches, ghosts seen.
"""
import json
import sys

import numpy as np

from pardem.protocols.compression import build_case
from pardem.config import check_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.parallel.communicator import Communicator

out_path, steps = sys.argv[1], int(sys.argv[2])
comm = Communicator()
deck = check_deck(COMPRESS_SCHEMA, {
    "domain": {"box": [0.006, 0.004, 0.004], "radius": 0.25e-3},
    "loading": {"plate_speed": 2.0, "strain": 0.02, "ramp_time": 0.0},
    "parallel": {"slab_axis": "x"},
    "run": {"skin": 0.01e-3},
})
case = build_case(comm, deck)
sim = case.sim
stats = {"steps": 0, "mismatches": 0, "ghosts_checked": 0, "missing_ghosts": 0}


def check_ghosts(s):
    e = s.elements
    n = e.n_owned
    owners = comm.comm.allgather((e.gid[:n], e.x[:n], e.v[:n], e.w[:n], e.q[:n], e.rot[:n].reshape(n, 9)))
    gid = np.concatenate([o[0] for o in owners])
    order = np.argsort(gid)
    table = [np.concatenate([o[k] for o in owners])[order] for k in range(1, 6)]
    rows = np.searchsorted(gid[order], e.gid[n:])
    for arr, ref in zip((e.x, e.v, e.w, e.q, e.rot.reshape(-1, 9)), table):
        stats["mismatches"] += int(np.count_nonzero(np.any(arr[n:] != ref[rows], axis=1)))
    # brute force: every other rank's element closer than the interaction range (ghost range
    # minus skin: each end may have moved skin / 2 since the rebuild) to an owned row is a ghost
    d = sim.domain
    x_all = table[0]
    dist = np.linalg.norm(e.x[:n, None, :] - x_all[None, :, :], axis=2).min(axis=0) if n else np.full(len(gid), np.inf)
    needed = np.setdiff1d(gid[order][dist < d.ghost_range - d.skin], e.gid[:n])
    stats["missing_ghosts"] += int(len(np.setdiff1d(needed, e.gid[n:])))
    stats["ghosts_checked"] += int(e.n_total - n)
    stats["steps"] += 1


update = sim.domain.update


def update_then_check(*args, **kwargs):
    result = update(*args, **kwargs)
    check_ghosts(result)   # the rows after this update (new ones after a rebuild)
    return result


sim.domain.update = update_then_check
sim.run(steps)
total = {k: int(comm.sum(v)) for k, v in stats.items()}
total["rebuilds"] = sim.domain.rebuilds
if comm.rank == 0:
    with open(out_path, "w") as fh:
        json.dump(total, fh)
