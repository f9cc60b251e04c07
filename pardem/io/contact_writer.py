"""Contact network writer: at its steps, every touching pair once, into one HDF5 file.

``ContactWriter`` is an operation (``trigger``, ``at_end``, ``__call__(sim)``): pass it to
``sim.run(n, operations=[writer])``. The call is collective: every rank selects the pairs it
counts (``Contacts.counted_once``: those whose lower-gid end it owns, so a pair held by two ranks
is counted by one), the rows are gathered with ``Communicator.allgatherv`` and rank 0 writes.

File layout (``path``), one group per call::

    /step_SSSSSSSS           (8-digit step count) attributes ``step``, ``time`` [s], ``law``
        gid                  int64 [m, 2]: the pair's global ids, lower first (grain i, then j)
        branch               float64 [m, 3]: ``x_j + s - x_i`` [m] (``s`` the periodic image shift)
        normal_force         float64 [m, 3]: normal force on i, ``-fn n`` [N] (``n = branch / |branch|``)
        tangential_force     float64 [m, 3]: tangential force on i [N] (the stored history)
        overlap              float64 [m]: ``R_i + R_j - |branch|`` [m], > 0
        sliding              uint8 [m]: 1 when ``|F_t|`` sits on the Coulomb cap ``mu fn``

Rows are sorted by ``(gid_i, gid_j)``; grain j feels the opposite forces. The pairs are those in
contact at the last force evaluation (centre distance below the sum of the radii, as the kernels
test it). The forces are the contact law's elastic parts, ``fn`` its elastic normal force
(``elastic_normal_force``) and ``F_t`` its stored tangential force: with an undamped law exactly
the forces the step applied (a dashpot's share depends on the half-step velocities of the force
evaluation, which the step no longer holds; a cement's force is not written). ``sliding`` compares
``|F_t|`` with ``mu fn`` to a relative 1e-9 (the cap's rescaling rounds).

An existing file is never overwritten unless asked: ``mode="new"`` (default) refuses
(FileExistsError on every rank) when ``path`` exists, ``mode="append"`` adds groups to it (a
restarted run; a step already in the file is refused), ``mode="overwrite"`` replaces it.
"""
import os

import h5py
import numpy as np

from pardem.physics.contact_frame import pair_geometry
from pardem.physics.contact_laws import LAWS
from pardem.triggers import as_trigger

MODES = ("new", "append", "overwrite")
SLIDING_TOLERANCE = 1e-9     # relative: |F_t| >= (1 - tol) mu fn counts as sliding
_FLOATS = 11                 # gathered columns: branch (3), fn (3), ft (3), overlap, sliding


def group_name(step):
    return f"step_{int(step):08d}"


def local_contacts(sim):
    """This rank's share of the contact network: ``(gid [m, 2] int64, values [m, 11] float64)``
    (columns: branch [m], normal force [N], tangential force [N], overlap [m], sliding 0/1)."""
    c, e = sim.contacts, sim.elements
    once = np.flatnonzero(c.counted_once(e.n_owned))
    i, j = c.i[once], c.j[once]
    shift = None if c.shift is None else np.ascontiguousarray(c.shift[once])
    d, n, _, delta = pair_geometry(i, j, shift, e.x, e.radius)
    rsum = e.radius[i] + e.radius[j]
    # the kernels' own test (pair_loop.touching), the same bits
    touching = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2] < rsum * rsum
    i, j, d, n, delta = i[touching], j[touching], d[touching], n[touching], delta[touching]
    ft = c.history[once[touching], :3]
    fn = c.law.elastic_normal_force(c.params, e.radius[i], e.radius[j], delta)
    cap = float(c.params.friction) * fn
    sliding = np.sum(ft * ft, axis=1) >= (cap * (1.0 - SLIDING_TOLERANCE)) ** 2
    values = np.empty((len(i), _FLOATS))
    values[:, 0:3] = d
    values[:, 3:6] = -fn[:, None] * n
    values[:, 6:9] = ft
    values[:, 9] = delta
    values[:, 10] = sliding & (cap > 0.0)
    return np.stack([e.gid[i], e.gid[j]], axis=1).astype(np.int64), values


class ContactWriter:
    """Writes the contact network of ``sim`` to ``path`` (HDF5, module docstring) on the steps of
    ``trigger`` (a ``pardem.triggers`` trigger, or a period [steps]) and, with ``at_end``, after the
    last step of each run. mode : "new" (refuse an existing file), "append" or "overwrite".
    ``steps`` lists the steps this object wrote (every rank)."""

    def __init__(self, path, trigger=100, mode="new", at_end=False):
        self.trigger, self.at_end = as_trigger(trigger), bool(at_end)
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
            raise ValueError(f"path must be a file name, got {path!r}")
        self.path = os.fspath(path)
        self.mode = mode
        self.steps = []
        self._opened = False

    def _write(self, sim, gid, values, first):
        """Rank 0's part; returns an error message or None."""
        exists = os.path.exists(self.path)
        if first and exists and self.mode == "new":
            return (f"{self.path} exists: refusing to overwrite it (mode='new'); use "
                    "mode='append' to add to it or mode='overwrite' to replace it")
        file_mode = "w" if first and self.mode == "overwrite" else "a"
        name = group_name(sim.step_count)
        try:
            parent = os.path.dirname(self.path)
            if parent:
                os.makedirs(parent, exist_ok=True)
            with h5py.File(self.path, file_mode) as fh:
                if name in fh:
                    return f"{self.path} already holds {name}: refusing to overwrite it"
                g = fh.create_group(name)
                g.attrs["step"] = int(sim.step_count)
                g.attrs["time"] = float(sim.time)
                g.attrs["law"] = next(k for k, row in LAWS.items() if row is sim.contacts.law)
                order = np.lexsort((gid[:, 1], gid[:, 0]))
                g["gid"] = gid[order]
                v = values[order]
                g["branch"] = v[:, 0:3]
                g["normal_force"] = v[:, 3:6]
                g["tangential_force"] = v[:, 6:9]
                g["overlap"] = v[:, 9]
                g["sliding"] = v[:, 10].astype(np.uint8)
        except OSError as exc:
            return f"cannot write {self.path}: {exc}"
        return None

    def __call__(self, sim):
        if sim.contacts is None:
            raise ValueError("ContactWriter: this simulation has no contacts (System.contacts)")
        if self.steps and self.steps[-1] == sim.step_count:
            return                   # the end-of-run call after a periodic one
        gid, values = local_contacts(sim)
        comm = sim.comm
        gid = comm.allgatherv(gid)
        values = comm.allgatherv(values)
        # one row per pair even if two ranks counted it (they cannot: one owns the lower gid)
        _, first_row = np.unique(gid[:, 0] * (np.int64(1) << 31) + gid[:, 1], return_index=True)
        gid, values = gid[first_row], values[first_row]
        err = self._write(sim, gid, values, not self._opened) if comm.is_root else None
        self._opened = True
        err = comm.bcast(err)
        if err is not None:
            raise FileExistsError(err) if "refusing" in err else OSError(err)
        self.steps.append(int(sim.step_count))
