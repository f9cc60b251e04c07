"""Periodic replication of a granular case: ``k_x x k_y (x k_z)`` copies of a periodic packing.

``replicate(comm, case, copies)`` gathers the state (``pardem.engine.open_cell.gather_state``),
lays the copies side by side in a cell ``k_a`` times longer along each periodic axis a, and builds
the new case with ``pardem.engine.system.build`` (the one builder) from the case's description:

* copy ``c = (c_x, c_y, c_z)`` (row-major, ``c_index = (c_x k_y + c_y) k_z + c_z``) holds the grains
  at ``x + c L`` (``L`` the old cell edges) with gids ``c_index G + gid``, ``G`` the largest gid
  plus one (N grains numbered 0 .. N-1: G = N): copy 0 keeps the original gids (its grains can be
  followed through the replication), the other copies get fresh ones above them; ``case.origin_gid``
  holds the original gid of each grain (``gid mod G``);
* velocities, spins, orientations, radii, masses and inertias are copied, and the contact history
  of every pair: a pair ``(i, j)`` whose partner j lies in the image ``-m`` of the old cell
  (``m = round((x_j - x_i) / L)`` per axis, the minimum image: contacts are shorter than half a
  cell) joins copy ``c`` of i to copy ``c - m`` (mod k) of j. When the new gids reverse the
  order of a pair, the history's vector columns (the tangential forces on the lower-gid grain,
  ``pardem.physics.contact_frame``; the cement's too) change sign, the scalar columns stay;
* the cell keeps the periodic axes, the 2D mode (dimension, thickness), the contact law and its
  parameters, time step, skin, damping, slab axis and balance period; it does not deform (rate 0,
  no servo: a driver sets its own), and the case starts at step 0, time 0.

The copies are then in the state of the original (the new case computes the forces of its
initial state before its first step, which for moving grains adds one tangential increment
``v_rel dt`` to the histories, as any new case does; for a packing at rest it adds nothing): every grain has the same neighbours at the
same separations and histories, so the same contact forces and the same (im)balance
(``tests/test_response.py`` checks the forces pair by pair against the original's).
"""
import numpy as np

from pardem.engine import granular
from pardem.engine.system import regrown
from pardem.engine.open_cell import gather_state

VECTOR_COLUMNS = {3: (slice(0, 3),), 9: (slice(0, 3), slice(3, 6))}   # history widths -> vector columns


def _copies(copies, cell):
    k = np.ones(3, dtype=np.int64)
    c = list(copies)
    if len(c) not in (2, 3) or any(isinstance(v, bool) or int(v) != v or int(v) < 1 for v in c):
        raise ValueError(f"copies = {copies!r}: expected 2 or 3 integers >= 1 (copies along x, y[, z])")
    k[:len(c)] = [int(v) for v in c]
    for d in range(3):
        if k[d] > 1 and not bool(cell.periodic[d]):
            raise ValueError(f"copies along {'xyz'[d]} = {k[d]}: that axis is not periodic (only a periodic "
                             "packing can be replicated)")
    return k


def replicate(comm, case, copies):
    """A new ``GranularCase`` of ``copies`` = ``(k_x, k_y)`` or ``(k_x, k_y, k_z)`` copies of the
    periodic ``case`` (module docstring). Collective; every rank gets its slab of the new case."""
    sim = case.sim
    cell = sim.cell
    k = _copies(copies, cell)
    grains, pairs = gather_state(comm, sim)
    gid = grains["gid"]
    n = len(gid)
    G = int(gid[-1]) + 1 if n else 0          # the copies' gids lie above the original's
    L, lo = cell.length.copy(), cell.lo.copy()
    per = cell.periodic
    offsets = np.stack(np.meshgrid(np.arange(k[0]), np.arange(k[1]), np.arange(k[2]), indexing="ij"),
                       axis=-1).reshape(-1, 3)                          # copy index -> (c_x, c_y, c_z)
    n_copies = len(offsets)
    x = grains["x"]
    xs = np.concatenate([x + offsets[m] * L for m in range(n_copies)])
    tile = lambda a: np.concatenate([a] * n_copies)                     # noqa: E731
    # the pairs: the partner's image m (minimum image along the periodic axes)
    gi, gj, hist = pairs["gid_i"], pairs["gid_j"], pairs["history"]
    ri, rj = np.searchsorted(gid, gi), np.searchsorted(gid, gj)      # rows of the pairs' ends
    sep = x[rj] - x[ri]
    m = np.where(per, np.round(sep / np.where(per, L, 1.0)), 0.0).astype(np.int64)
    if np.any(np.abs(sep - m * L)[:, per] >= 0.5 * L[per]):
        raise ValueError("replicate: a contact spans half a cell (the cell is too small)")
    stride = np.array([k[1] * k[2], k[2], 1], dtype=np.int64)
    new_i, new_j, new_h = [], [], []
    vec = VECTOR_COLUMNS.get(hist.shape[1], (slice(0, 3),))
    for ci in range(n_copies):
        cj = np.mod(offsets[ci][None, :] - m, k[None, :]) @ stride      # copy index of j's image
        a = ci * G + gi
        b = cj * G + gj
        swap = a > b
        h = hist.copy()
        for s in vec:
            h[swap, s] = -h[swap, s]
        new_i.append(np.where(swap, b, a))
        new_j.append(np.where(swap, a, b))
        new_h.append(h)
    table = {"gid_i": np.concatenate(new_i).astype(np.int64), "gid_j": np.concatenate(new_j).astype(np.int64),
             "history": np.ascontiguousarray(np.concatenate(new_h)) if new_h else hist}
    length = L * k
    gids = np.concatenate([c * G + gid for c in range(n_copies)]).astype(np.int64)
    new = granular.build_case(comm, regrown(sim, xs, tile(grains["radius"]), tile(grains["v"]),
                                            tile(grains["w"]), lo, length, per, gids=gids))
    e = new.sim.elements
    row = np.searchsorted(gids, e.gid)
    for name in ("q", "mass", "inertia"):
        getattr(e, name)[:] = tile(grains[name])[row]
    e.inv_mass[:] = 1.0 / e.mass
    e.inv_inertia[:] = 1.0 / e.inertia
    e.refresh_rotations()
    new.sim.contacts.rebuild(e, new.sim.bonds, table)
    new.origin_gid = tile(gid).astype(np.int64)
    new.extras["replicated"] = {"copies": k.tolist(), "n_original": int(n)}
    return new


__all__ = ["replicate"]
