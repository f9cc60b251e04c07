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

        normal_damping       float64 [m, 3]: the law's normal dashpot share on i [N] (0 for an undamped
                             or cemented law)
        tangential_damping   float64 [m, 3]: the law's tangential dashpot share on i [N] (idem)

Rows are sorted by ``(gid_i, gid_j)``; grain j feels the opposite forces. The pairs are those in
contact at the last force evaluation (centre distance below the sum of the radii, as the kernels
test it). ``normal_force`` and ``tangential_force`` are the contact law's elastic parts, ``fn`` its
elastic normal force (``elastic_normal_force``) and ``F_t`` its stored tangential spring force:
with an undamped law exactly the forces the step applied. The dashpot shares are the law's own
kernel evaluated on the pair at the current (end-of-step) velocities, the periodic cell's affine
motion included, with a zero time step (so the spring is not advanced): the total force of the
pair is ``normal_force + normal_damping + tangential_force + tangential_damping``, the dashpot
clipped and capped as the law does it. The step itself applied the dashpot at the half-step
velocities, which it no longer holds: the written share differs from the applied one by the
velocity change over half a step. A cement's force is not written (nor, for a cemented law, the
dashpot shares: zeros). ``sliding`` compares ``|F_t|``
with ``mu fn`` to a relative 1e-9 (the cap's rescaling rounds), ``fn`` the whole normal force (the
dashpot's share included, as the laws cap the spring).

An existing file is never overwritten unless asked: ``mode="new"`` (default) refuses
(FileExistsError on every rank) when ``path`` exists, ``mode="append"`` adds groups to it (a
restarted run; a step already in the file is refused), ``mode="overwrite"`` replaces it.
"""
import os
from types import SimpleNamespace

import h5py
import numpy as np

from pardem.physics.contact_frame import pair_geometry
from pardem.physics.contact_laws import LAWS
from pardem.triggers import as_trigger

MODES = ("new", "append", "overwrite")
SLIDING_TOLERANCE = 1e-9     # relative: |F_t| >= (1 - tol) mu fn counts as sliding
# gathered columns: branch (3), fn (3), ft (3), overlap, sliding, dashpot normal (3), dashpot
# tangential (3), centre of i (3)
_FLOATS = 20


def group_name(step):
    return f"step_{int(step):08d}"


def touching_pairs(sim):
    """The touching pairs of this rank's contact list (every pair it holds, ghosts' too):
    ``(p, i, j, d, n, delta)``: list positions [m], rows, branch [m, 3] [m], unit normal [m, 3],
    overlap [m] [m]; the kernels' own test and geometry (``pair_loop.touching``, the same bits)."""
    c, e = sim.contacts, sim.elements
    shift = c.shift
    d, n, _, delta = pair_geometry(c.i, c.j, shift, e.x, e.radius)
    rsum = e.radius[c.i] + e.radius[c.j]
    p = np.flatnonzero(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2] < rsum * rsum)
    return p, c.i[p], c.j[p], d[p], n[p], delta[p]


def coordination(sim):
    """Touching contacts per row [n_total] int32, counted from this rank's contact list: exact for
    the owned rows (a rank holds every pair of the grains it owns), partial for ghosts. Zeros
    without contacts."""
    e = sim.elements
    if sim.contacts is None:
        return np.zeros(e.n_total, dtype=np.int32)
    _, i, j, _, _, _ = touching_pairs(sim)
    return (np.bincount(i, minlength=e.n_total) + np.bincount(j, minlength=e.n_total)).astype(np.int32)


def _pair_forces(sim, p):
    """The force on i [m, 3] [N] of the list pairs ``p`` by the law's kernel at the current
    velocities (the cell's affine motion included) with a zero time step (the spring is not
    advanced), on scratch copies (the state is not touched): each pair on its own two scratch rows,
    so the per-row sums are per-pair forces."""
    c, e = sim.contacts, sim.elements
    i, j, m = c.i[p], c.j[p], len(p)
    rows = np.empty(2 * m, dtype=np.int64)
    rows[0::2], rows[1::2] = i, j
    scratch = SimpleNamespace(x=e.x[rows], v=e.v[rows], w=e.w[rows], radius=e.radius[rows],
                              mass=e.mass[rows], f=np.zeros((2 * m, 3)), t=np.zeros((2 * m, 3)),
                              n_owned=2 * m)
    pi = np.arange(0, 2 * m, 2, dtype=np.int32)
    shift = None if c.shift is None else np.ascontiguousarray(c.shift[p])
    rate = None if c.shift is None else np.asarray(c.cell.rate, dtype=np.float64)
    history = np.ascontiguousarray(c.history[p]).copy()
    c.law.compute(c.params, scratch, pi, pi + 1, history, 0.0, shift, rate, None,
                  with_energy=False, with_stress=False)
    return scratch.f[0::2]


def damping_parts(sim, p, n, elastic):
    """The dashpot shares of the list pairs ``p`` (touching, unit normals ``n`` [m, 3], elastic
    force on i ``elastic`` [m, 3] [N]: normal plus stored tangential): ``(normal [m, 3],
    tangential [m, 3])`` [N] on i at the current velocities (module docstring): the law's force
    less its elastic parts."""
    params = sim.contacts.params
    # a cemented law's kernel adds the cement's force, which is no dashpot: shares left at zero
    if len(p) == 0 or not getattr(params, "damped", False) or getattr(params, "cemented", False):
        return np.zeros((len(p), 3)), np.zeros((len(p), 3))
    df = _pair_forces(sim, p) - elastic
    normal = np.sum(df * n, axis=1)[:, None] * n
    return normal, df - normal


def local_contacts(sim):
    """This rank's share of the contact network: ``(gid [m, 2] int64, values [m, 20] float64)``
    (columns: branch [m], normal force [N], tangential force [N], overlap [m], sliding 0/1, normal
    and tangential dashpot shares [N], centre of i [m])."""
    c, e = sim.contacts, sim.elements
    p, i, j, d, n, delta = touching_pairs(sim)
    once = i < e.n_owned       # Contacts.counted_once: the lower-gid end owned
    p, i, j, d, n, delta = p[once], i[once], j[once], d[once], n[once], delta[once]
    ft = c.history[p, :3]
    fn = c.law.elastic_normal_force(c.params, e.radius[i], e.radius[j], delta)
    values = np.empty((len(i), _FLOATS))
    values[:, 0:3] = d
    values[:, 3:6] = -fn[:, None] * n
    values[:, 6:9] = ft
    values[:, 9] = delta
    values[:, 11:14], values[:, 14:17] = damping_parts(sim, p, n, values[:, 3:6] + ft)
    # the law caps the spring at mu times the whole normal force, its dashpot included
    cap = float(c.params.friction) * (fn - np.sum(values[:, 11:14] * n, axis=1))
    sliding = np.sum(ft * ft, axis=1) >= (cap * (1.0 - SLIDING_TOLERANCE)) ** 2
    values[:, 10] = sliding & (cap > 0.0)
    values[:, 17:20] = e.x[i]
    return np.stack([e.gid[i], e.gid[j]], axis=1).astype(np.int64), values


def gather_contacts(sim):
    """Collective: the whole contact network on every rank, ``(gid [m, 2], values [m, 20])``
    sorted by ``(gid_i, gid_j)`` (``local_contacts`` columns)."""
    gid, values = local_contacts(sim)
    comm = sim.comm
    gid = comm.allgatherv(gid)
    values = comm.allgatherv(values).reshape(-1, _FLOATS)
    gid = gid.reshape(-1, 2)
    # one row per pair even if two ranks counted it (they cannot: one owns the lower gid)
    _, first_row = np.unique(gid[:, 0] * (np.int64(1) << 31) + gid[:, 1], return_index=True)
    gid, values = gid[first_row], values[first_row]
    order = np.lexsort((gid[:, 1], gid[:, 0]))
    return gid[order], values[order]


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
                g["gid"] = gid
                v = values
                g["branch"] = v[:, 0:3]
                g["normal_force"] = v[:, 3:6]
                g["tangential_force"] = v[:, 6:9]
                g["overlap"] = v[:, 9]
                g["sliding"] = v[:, 10].astype(np.uint8)
                g["normal_damping"] = v[:, 11:14]
                g["tangential_damping"] = v[:, 14:17]
        except OSError as exc:
            return f"cannot write {self.path}: {exc}"
        return None

    def __call__(self, sim):
        if sim.contacts is None:
            raise ValueError("ContactWriter: this simulation has no contacts (System.contacts)")
        if self.steps and self.steps[-1] == sim.step_count:
            return                   # the end-of-run call after a periodic one
        gid, values = gather_contacts(sim)
        comm = sim.comm
        err = self._write(sim, gid, values, not self._opened) if comm.is_root else None
        self._opened = True
        err = comm.bcast(err)
        if err is not None:
            raise FileExistsError(err) if "refusing" in err else OSError(err)
        self.steps.append(int(sim.step_count))
