"""Remove the periodicity of a granular case along some axes (biaxial tests, point-load response).

``open_axes(comm, case, axes, keep)`` gathers the state of ``case`` over the ranks (the
communicator's ``allgather``; no raw MPI here), unwraps it into the former cell and builds a new
case with ``pardem.engine.system.build`` (the one builder) from the case's description, in which the axes
``axes`` are no longer periodic:

* positions along an opened axis are brought into the former cell ``[lo, lo + L)`` (the box along
  that axis); along the axes that stay periodic ``build`` wraps them as usual;
* ``keep(positions [n, 3]) -> bool [n]`` (optional) selects the grains retained, from the
  unwrapped positions ordered by the old gid;
* the grains kept keep their gids (a grain can be followed through the opening, e.g. in one
  ParaView series; the order of every pair is kept, so the contact keys stay ordered);
  ``case.origin_gid`` [m] holds them too (the same on every rank);
* velocities, spins, orientations, radii and masses (inertias) are carried over, and the
  tangential history of every pair that still exists; a pair that touched across the former
  boundary of an opened axis (its two centres, unwrapped, are more than half a period apart along
  that axis) is dropped, as are the pairs of removed grains;
* the 2D mode (dimension, thickness), the contact law and parameters, time step, skin, damping,
  slab axis and balance period are kept; the cell no longer deforms (rate 0, no servo: a driver
  sets its own loading), and the new case starts at step 0, time 0.

The forces of the first step are those of the old state on the retained pairs (the history and
positions are the same), which ``tests/test_biaxial.py`` checks pair by pair.
"""
import numpy as np

from pardem.engine import granular
from pardem.engine.system import regrown
from pardem.engine.contacts import KEY_BASE

AXES = {"x": 0, "y": 1, "z": 2}
_FIELDS = ("gid", "x", "v", "w", "q", "radius", "mass", "inertia")


def _axis_indices(axes, cell):
    if isinstance(axes, str):
        axes = (axes,)
    out = []
    for a in axes:
        if a not in AXES:
            raise ValueError(f"axes: {a!r} is not an axis name (expected 'x', 'y' or 'z')")
        d = AXES[a]
        if not bool(cell.periodic[d]):
            raise ValueError(f"axes: {a!r} is not periodic in this case (nothing to open)")
        out.append(d)
    if not out:
        raise ValueError("axes: name at least one periodic axis to open ('x', 'y' or 'z')")
    return sorted(set(out))


def gather_state(comm, sim):
    """Every grain's ``gid, x, v, w, q, radius, mass, inertia`` ordered by gid (dict of arrays,
    the same on every rank; collective), and every contact ``(gid_i, gid_j, history)`` with a
    non-zero history, each pair once."""
    e, n = sim.elements, sim.elements.n_owned
    mine = {k: getattr(e, k)[:n] for k in _FIELDS}
    c = sim.contacts
    live = np.any(c.history != 0.0, axis=1)
    mine["pair_keys"] = c.keys[live]
    mine["pair_history"] = c.history[live]
    parts = comm.allgather(mine)
    cat = {k: np.concatenate([p[k] for p in parts]) for k in mine}
    o = np.argsort(cat["gid"], kind="stable")
    grains = {k: cat[k][o] for k in _FIELDS}
    # a boundary pair is held by both ranks with bitwise-equal histories: keep it once
    keys, first = np.unique(cat["pair_keys"], return_index=True)
    pairs = {"gid_i": keys // KEY_BASE, "gid_j": keys % KEY_BASE, "history": cat["pair_history"][first]}
    return grains, pairs


def open_axes(comm, case, axes, keep=None):
    """A new ``GranularCase`` from ``case`` with the periodic axes ``axes`` (e.g. ``("y",)`` or
    ``("x", "y")``) opened; ``keep`` an optional ``positions [n, 3] -> bool [n]`` (module
    docstring). Collective; every rank gets its slab of the new case."""
    sim = case.sim
    cell = sim.cell
    opened = _axis_indices(axes, cell)
    grains, pairs = gather_state(comm, sim)
    lo, length = cell.lo.copy(), cell.length.copy()
    x = grains["x"].copy()
    for d in opened:
        x[:, d] = lo[d] + np.mod(x[:, d] - lo[d], length[d])
        # mod may round up to exactly lo + L: keep the half-open box
        x[:, d] = np.where(x[:, d] >= lo[d] + length[d], np.nextafter(lo[d] + length[d], -np.inf), x[:, d])
    gid = grains["gid"]
    if keep is None:
        kept = np.ones(len(gid), dtype=bool)
    else:
        kept = np.asarray(keep(x.copy()), dtype=bool)
        if kept.shape != gid.shape:
            raise ValueError(f"keep must return a bool mask of shape ({len(gid)},), got {kept.shape}")
    if not kept.any():
        raise ValueError("keep retained no grain")
    # the pairs that survive: both ends kept, not across an opened boundary
    pos_of = {k: np.searchsorted(gid, pairs[k]) for k in ("gid_i", "gid_j")}
    ok = kept[pos_of["gid_i"]] & kept[pos_of["gid_j"]]
    for d in opened:
        ok &= np.abs(x[pos_of["gid_j"], d] - x[pos_of["gid_i"], d]) < 0.5 * length[d]
    table = {"gid_i": np.asarray(pairs["gid_i"][ok], dtype=np.int64),
             "gid_j": np.asarray(pairs["gid_j"][ok], dtype=np.int64),
             "history": np.ascontiguousarray(pairs["history"][ok])}
    periodic = cell.periodic.copy()
    periodic[opened] = False
    kept_gid = gid[kept]
    new = granular.build_case(comm, regrown(sim, x[kept], grains["radius"][kept], grains["v"][kept],
                                            grains["w"][kept], lo, length, periodic, gids=kept_gid))
    e = new.sim.elements
    # orientations and masses by gid, on owned and ghost rows alike (build made them from radii)
    row = np.searchsorted(kept_gid, e.gid)
    for k in ("q", "mass", "inertia"):
        getattr(e, k)[:] = grains[k][kept][row]
    e.inv_mass[:] = 1.0 / e.mass
    e.inv_inertia[:] = 1.0 / e.inertia
    e.refresh_rotations()
    # the same call build made, now with the carried history (looked up by the new gid pairs)
    new.sim.contacts.rebuild(e, new.sim.bonds, table)
    new.origin_gid = kept_gid.copy()
    new.extras["opened"] = {"axes": ["xyz"[d] for d in opened], "n_before": int(len(gid))}
    return new


__all__ = ["open_axes", "gather_state", "AXES"]
