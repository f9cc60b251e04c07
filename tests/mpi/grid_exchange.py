"""Run under mpiexec: the grid's per-rank verbs with real messages, against the one-process bookkeeping.

Every rank builds the same point set (a pour: 80 % in the lowest fifth along z, gids shuffled) and
takes a stripe of it; the cuts come from ``GridDecomposition.balanced`` with ``Communicator.sum``
(each rank its stripe) and must equal those of one process holding every point; the points then go
to their owners, and the staged exchange runs with point-to-point messages (``stage_sends`` on the
rows each rank holds, 2 messages per stage, a rank's own images through a message to itself); each
rank's ghosts (gid, shift) must equal ``staged_ghosts`` of one process. Writes JSON (rank 0).

argv: out.json, grid as JSON ([px, py, pz]), periodic as JSON ([bool] * 3).
"""
import json
import sys

import numpy as np

from pardem.parallel.communicator import Communicator
from pardem.parallel.grid import GridDecomposition

out_path, grid, periodic = sys.argv[1], tuple(json.loads(sys.argv[2])), json.loads(sys.argv[3])
comm = Communicator()
mpi = comm.comm
P, me = comm.size, comm.rank
assert P == np.prod(grid)

rng = np.random.default_rng(17)
L = np.array([1.0, 0.9, 1.2])
n = 3000
x = rng.uniform(0.0, 1.0, (n, 3)) * L
low = rng.random(n) < 0.8
x[:, 2] = np.where(low, rng.uniform(0.0, 0.2, n), rng.uniform(0.2, 1.0, n)) * L[2]
gid = rng.permutation(n).astype(np.int64)
r = 0.1

even = GridDecomposition(grid, [0, 0, 0], L, periodic)
stripe = slice(me, None, P)
g = even.balanced(x[stripe], allsum=comm.sum, gid=gid[stripe], min_width=r)
one = even.balanced(x, gid=gid, min_width=r)
same_cuts = all(np.array_equal(g.cuts[a], one.cuts[a]) and np.array_equal(g.cut_gids[a], one.cut_gids[a])
                for a in range(3))

# to the owners (a test's shortcut for the migration)
xs = g.wrapped(x[stripe])
owner = g.owner(xs, gid[stripe])
got = mpi.alltoall([(gid[stripe][owner == q], xs[owner == q]) for q in range(P)])
my_gid = np.concatenate([a for a, _ in got])
my_x = np.concatenate([b for _, b in got])
shifts = np.zeros((len(my_gid), 3), dtype=np.int64)
n_owned = len(my_gid)

messages = 0
for axis in range(3):
    held = my_x + shifts * g.length
    sends = {side: (nb, (my_gid[rows], my_x[rows], shifts[rows] + shift))
             for side, nb, rows, shift in g.stage_sends(me, axis, held, r)}
    reqs = [mpi.isend(payload, dest=nb, tag=100 + 2 * axis + (side > 0)) for side, (nb, payload) in sends.items()]
    parts = []
    for side in (-1, 1):
        src = g.neighbour(me, axis, -side)     # who sent me its side-message
        if src is not None:
            parts.append(mpi.recv(source=src[0], tag=100 + 2 * axis + (side > 0)))
    for q in reqs:
        q.wait()
    messages += sum(1 for nb, _ in sends.values() if nb != me)
    for pg, px_, ps in parts:
        my_gid = np.concatenate([my_gid, pg])
        my_x = np.concatenate([my_x, px_])
        shifts = np.concatenate([shifts, ps])

mine = {(int(a), tuple(int(v) for v in s)) for a, s in zip(my_gid[n_owned:], shifts[n_owned:])}
ghosts, _ = one.staged_ghosts(x, r, gid)
pts, shs = ghosts[me]
expected = {(int(gid[p]), tuple(int(v) for v in s)) for p, s in zip(pts, shs)}
owned_ok = set(my_gid[:n_owned].tolist()) == set(gid[one.owner(x, gid) == me].tolist())
ok = comm.allgather({"rank": me, "same_cuts": bool(same_cuts), "owned_ok": bool(owned_ok),
                     "ghosts_equal": mine == expected, "ghosts": len(mine),
                     "duplicates": int(len(my_gid) - n_owned - len(mine)), "messages": messages})
if me == 0:
    with open(out_path, "w") as fh:
        json.dump(ok, fh)
