"""Fixes: loads and kinematic constraints applied after the force computation (LAMMPS' ``fix``).

A fix is any object with a ``post_force(sim)`` method. ``Simulation.compute_forces`` calls
``fix.post_force(sim)`` for every ``fix in sim.fixes``, on every rank, after the bond, wall, contact
and damping forces of the step, and before the second half kick of velocity Verlet. A fix only
touches the owned rows ``[0, sim.elements.n_owned)`` (ghost rows are copies of other ranks' rows).

Elements are chosen by global id (``elements.gid``), never by row: rows are reordered whenever
elements migrate between ranks. Each fix resolves its gids to this rank's owned rows once per
``Elements`` object (the parallel layer builds a new one at every rebuild) and checks the cached rows
each step (``O(k)`` for ``k`` chosen elements), so it works the same on one rank and on several.

How the constraints interact with velocity Verlet (``pardem.physics.verlet``): after ``post_force``
the step ends with ``v += dt/2 f/m``; the next starts with ``v += dt/2 f/m; x += dt v``. A fix that
sets a velocity component ``v_d = V`` and the force component ``f_d = 0`` therefore keeps ``v_d = V``
through both half kicks, and the element moves by exactly ``dt V`` (in floating point:
``x <- x + dt V``) per step. ``Clamp`` is the case ``V = 0``: the position stays bitwise the same.
The same holds for the angular velocity and the torque.

Order: fixes run in the order of ``sim.fixes``, and a constraint only holds against the forces
added before it. Loads (``Gravity``, ``ExternalForce``: ``stage = 0``) must therefore come before
constraints (``Clamp``, ``PrescribedVelocity``: ``stage = 1``). ``add(sim, *fixes)`` inserts each fix
after those of its stage or lower, and the loads here raise ValueError at the first step if they
find a constraint before them in ``sim.fixes``. A fix of your own that adds forces should have
``stage = 0`` and be added with ``add``.

Usage::

    add(sim, Gravity(), Clamp(gids=[0]), ExternalForce(gids=[9], force=(0, 0, -1.0)))
    # sim.fixes is now [Gravity, ExternalForce, Clamp]

Reactions: ``Clamp`` and ``PrescribedVelocity`` keep the force (torque) they removed at the last
force evaluation in two forms: ``reaction`` [3] [N] and ``reaction_torque`` [3] [N m], this rank's
share (the sum over the chosen elements it owns: zero on a rank that owns none), and
``global_reaction``, ``global_reaction_torque`` [3], the totals over all ranks, the same on every
rank, as of the last step after which an operation ran or the end of the last ``sim.run`` (one
allreduce with the walls' forces, ``pardem.engine.particles.reduce_globals``): a script reads those
on any rank without a collective.

Units: SI (N, N m, m/s, rad/s, m/s^2).
"""
import weakref

import numpy as np

from pardem.physics.arguments import array, keywords, short

_AXES = "xyz"


def _gid_array(gids, name="gids"):
    """Unique global ids as a 1-D int64 array (order kept), or ValueError."""
    try:
        arr = np.asarray(gids)
    except (TypeError, ValueError):   # ragged nesting
        raise ValueError(f"{name} must be a non-empty 1-D sequence of element global ids, got "
                         f"{short(gids)}") from None
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D sequence of element global ids, got shape "
                         f"{np.shape(gids)}")
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind == "f" and np.all(np.abs(arr) < 2.0**63) and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise ValueError(f"{name} must be integer global ids (elements.gid), got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    if np.any(arr < 0):
        raise ValueError(f"{name} must be >= 0 (global ids), got {int(arr.min())}")
    if len(np.unique(arr)) != len(arr):
        raise ValueError(f"{name} must not repeat an element: got {len(arr)} ids, "
                         f"{len(np.unique(arr))} distinct")
    return arr


def _dof_mask(dofs, name):
    """Boolean [3] mask from a string of axes such as ``"xz"`` ("" = none)."""
    if dofs is None:
        dofs = ""
    if not isinstance(dofs, str) or any(c not in _AXES for c in dofs) or len(set(dofs)) != len(dofs):
        raise ValueError(f"{name} must be a string of distinct axes among 'x', 'y', 'z' (e.g. 'xyz', "
                         f"'z', ''), got {dofs!r}")
    return np.array([c in dofs for c in _AXES])


def _vectors(value, n, name, unit):
    """A [3] vector for every chosen element: ``value`` of shape [3] or [n, 3], finite."""
    arr = array(name, value, unit)
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (n, 3))
    elif arr.shape != (n, 3):
        raise ValueError(f"{name} must have shape (3,) or ({n}, 3) (one row per gid) {unit}, got "
                         f"shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite {unit}, got {short(value)}")
    return np.ascontiguousarray(arr)


LOAD, CONSTRAINT = 0, 1


def add(sim, *fixes):
    """Append ``fixes`` to ``sim.fixes`` keeping the stages in order (loads before constraints;
    a fix without a ``stage`` attribute counts as a load). Returns ``sim.fixes``. Every rank calls it.

    Between runs (once a run computed them: ``sim.initial_forces``) the forces of the current state, which the next step's
    first half kick uses, were computed without the new fix: it is applied to them at once (then
    the constraints after it again), so that it acts from the next step on exactly as if it had
    been there from the start. (Appending to ``sim.fixes`` directly skips this: the fix then
    acts from the second half of the next step.) A simulation just restored by ``pardem.load``
    (``sim.forces_restored``) holds the forces its checkpoint stored, which already include the
    fixes active when it was saved: adding those fixes again applies nothing at once, so the
    restart continues the saved run exactly (a fix the saved run did not have acts from the
    second half of the next step).
    """
    for fix in fixes:
        if not callable(getattr(fix, "post_force", None)):
            raise ValueError(f"a fix needs a post_force(sim) method, got {type(fix).__name__}")
        stage = getattr(fix, "stage", LOAD)
        at = len(sim.fixes)
        while at > 0 and getattr(sim.fixes[at - 1], "stage", LOAD) > stage:
            at -= 1
        sim.fixes.insert(at, fix)
        if getattr(sim, "forces_restored", False):
            continue
        if sim.step_count > 0 or getattr(sim, "initial_forces", False):
            fix.post_force(sim)
            for later in sim.fixes[at + 1:]:
                if getattr(later, "stage", LOAD) > LOAD:   # constraints are idempotent
                    later.post_force(sim)
    return sim.fixes


def check_order(sim, load):
    """ValueError if a constraint comes before the load ``load`` in ``sim.fixes``."""
    for fix in sim.fixes:
        if fix is load:
            return
        if getattr(fix, "stage", LOAD) > LOAD:
            raise ValueError(f"sim.fixes has the constraint {type(fix).__name__} before the load "
                             f"{type(load).__name__}: the load would undo it; put the loads first or "
                             f"use pardem.engine.fixes.add(sim, ...)")


class ElementSelection:
    """Global ids ``gids`` [k] resolved to this rank's owned rows, cached per ``Elements`` object.

    ``rows(elements)`` returns ``(rows, index)``: the owned rows holding some of the gids, and the
    position of each of those gids in ``gids`` (to pick per-element values). The first call checks,
    collectively (every rank calls it from ``post_force``), that every gid is owned by exactly one
    rank, and raises ValueError naming the missing ones otherwise.
    """

    def __init__(self, gids, name="gids"):
        self.gids = _gid_array(gids, name)
        self.name = name
        self._ref = None
        self._n_owned = -1
        self._rows = np.zeros(0, np.int64)
        self._index = np.zeros(0, np.int64)
        self._checked = False

    def _valid(self, e):
        if self._ref is None or self._ref() is not e or self._n_owned != e.n_owned:
            return False
        # rows could in principle be permuted in place: the check costs O(k)
        return len(self._rows) == 0 or np.array_equal(e.gid[self._rows], self.gids[self._index])

    def rows(self, elements, comm=None):
        e = elements
        if not self._valid(e):
            owned = e.gid[:e.n_owned]
            order = np.argsort(owned, kind="stable")
            pos = np.searchsorted(owned[order], self.gids)
            pos_c = np.minimum(pos, max(len(owned) - 1, 0))
            found = (pos < len(owned)) & (owned[order][pos_c] == self.gids) if len(owned) else \
                np.zeros(len(self.gids), bool)
            self._index = np.nonzero(found)[0].astype(np.int64)
            self._rows = order[pos_c[found]].astype(np.int64)
            self._ref = weakref.ref(e)
            self._n_owned = e.n_owned
            if not self._checked and comm is not None:
                counts = np.asarray(comm.sum(found.astype(np.float64)))
                self._checked = True
                if np.any(counts != 1):
                    missing = self.gids[counts != 1]
                    raise ValueError(f"{self.name} {missing[:5].tolist()}{' ...' if len(missing) > 5 else ''}"
                                     f" are not element global ids of this simulation (elements.gid, "
                                     f"0 .. n_elements - 1 for the builders)")
        return self._rows, self._index


class _Load:
    """Base of the loads: checks, once per list of fixes, that no constraint precedes them."""
    stage = LOAD
    _order_checked = None

    def _check_order(self, sim):
        key = tuple(map(id, sim.fixes))
        if self._order_checked != key:
            check_order(sim, self)
            self._order_checked = key


@keywords("Gravity")
class Gravity(_Load):
    """Uniform acceleration ``g`` [m/s^2] (shape [3], default ``(0, 0, -9.81)``): ``f += m g`` on
    every owned element."""
    def __init__(self, g=(0.0, 0.0, -9.81)):
        g_in = g
        g = array("g", g, "[m/s^2]")
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f"g must be a finite vector of shape (3,) [m/s^2], got {short(g_in)}")
        self.g = g

    def post_force(self, sim):
        self._check_order(sim)
        e = sim.elements
        n = e.n_owned
        e.f[:n] += e.mass[:n, None] * self.g


@keywords("ExternalForce")
class ExternalForce(_Load):
    """Constant force ``force`` [N] and optional torque ``torque`` [N m] (about the element's
    centre) on the elements of global ids ``gids`` [k].

    force, torque : shape [3] (the same on each element) or [k, 3] (row m for ``gids[m]``).
    The load can be changed between runs through ``self.force`` / ``self.torque`` ([k, 3] arrays).
    """
    def __init__(self, gids, force, torque=None):
        self.selection = ElementSelection(gids)
        k = len(self.selection.gids)
        self.force = _vectors(force, k, "force", "[N]").copy()
        self.torque = None if torque is None else _vectors(torque, k, "torque", "[N m]").copy()

    def post_force(self, sim):
        self._check_order(sim)
        e = sim.elements
        rows, idx = self.selection.rows(e, sim.comm)
        e.f[rows] += self.force[idx]
        if self.torque is not None:
            e.t[rows] += self.torque[idx]


@keywords("Clamp")
class Clamp:
    """Fixed degrees of freedom of the elements of global ids ``gids`` [k].

    dofs : translations held, a string of axes among ``"xyz"`` (default all three; ``""`` none);
    rotations : rotations held, likewise (default all three). The force (torque) and velocity
    (angular velocity) components of the held DOFs are zeroed every step, so with velocity Verlet the
    held coordinates of the position stay bitwise the same (and the orientation, when all rotations
    are held). The reaction of the clamp is the force it removed: ``self.global_reaction`` [3] [N]
    and ``self.global_reaction_torque`` [3] [N m], the totals on every rank (module docstring);
    ``self.reaction``, ``self.reaction_torque``: this rank's share at the last step.
    """
    stage = CONSTRAINT

    def __init__(self, gids, dofs="xyz", rotations="xyz"):
        self.selection = ElementSelection(gids)
        self.dofs = _dof_mask(dofs, "dofs")
        self.rotations = _dof_mask(rotations, "rotations")
        self.reaction = np.zeros(3)
        self.reaction_torque = np.zeros(3)
        self.global_reaction, self.global_reaction_torque = np.zeros(3), np.zeros(3)

    def post_force(self, sim):
        e = sim.elements
        rows, _ = self.selection.rows(e, sim.comm)
        if len(rows) == 0:
            self.reaction[:] = 0.0
            self.reaction_torque[:] = 0.0
            return
        d, r = self.dofs, self.rotations
        self.reaction[:] = np.where(d, -e.f[rows].sum(axis=0), 0.0)
        self.reaction_torque[:] = np.where(r, -e.t[rows].sum(axis=0), 0.0)
        if d.any():
            sub = np.ix_(rows, np.nonzero(d)[0])
            e.f[sub] = 0.0
            e.v[sub] = 0.0
        if r.any():
            sub = np.ix_(rows, np.nonzero(r)[0])
            e.t[sub] = 0.0
            e.w[sub] = 0.0


@keywords("PrescribedVelocity")
class PrescribedVelocity:
    """Imposed velocity ``velocity`` [m/s] (and optional ``angular_velocity`` [rad/s], world frame)
    of the elements of global ids ``gids`` [k].

    velocity, angular_velocity : shape [3] or [k, 3] (row m for ``gids[m]``). dofs : the velocity
    components imposed (axes among ``"xyz"``, default all); rotations : the angular velocity
    components imposed (default all when ``angular_velocity`` is given, none otherwise). Each step the
    imposed components of ``v`` (``w``) are set and those of ``f`` (``t``) zeroed, so the element
    moves by exactly ``dt * velocity`` per step on those axes. ``self.global_reaction`` [3] [N] and
    ``self.global_reaction_torque`` [3] [N m]: the force and torque removed (the load the drive
    exerts), totals on every rank (module docstring); ``self.reaction``, ``self.reaction_torque``:
    this rank's share at the last step. ``self.velocity`` may be changed between runs.
    """
    stage = CONSTRAINT

    def __init__(self, gids, velocity, angular_velocity=None, dofs="xyz", rotations=None):
        self.selection = ElementSelection(gids)
        k = len(self.selection.gids)
        self.velocity = _vectors(velocity, k, "velocity", "[m/s]").copy()
        self.angular_velocity = None if angular_velocity is None else \
            _vectors(angular_velocity, k, "angular_velocity", "[rad/s]").copy()
        self.dofs = _dof_mask(dofs, "dofs")
        if rotations is None:
            rotations = "xyz" if angular_velocity is not None else ""
        self.rotations = _dof_mask(rotations, "rotations")
        if self.rotations.any() and angular_velocity is None:
            raise ValueError(f"rotations = {rotations!r} needs angular_velocity (shape (3,) or ({k}, 3) "
                             f"[rad/s])")
        self.reaction = np.zeros(3)
        self.reaction_torque = np.zeros(3)
        self.global_reaction, self.global_reaction_torque = np.zeros(3), np.zeros(3)

    def post_force(self, sim):
        e = sim.elements
        rows, idx = self.selection.rows(e, sim.comm)
        if len(rows) == 0:
            self.reaction[:] = 0.0
            self.reaction_torque[:] = 0.0
            return
        d = np.nonzero(self.dofs)[0]
        self.reaction[:] = 0.0
        self.reaction_torque[:] = 0.0
        if len(d):
            sub = np.ix_(rows, d)
            self.reaction[d] = -e.f[sub].sum(axis=0)
            e.f[sub] = 0.0
            e.v[sub] = self.velocity[np.ix_(idx, d)]
        r = np.nonzero(self.rotations)[0]
        if len(r):
            sub = np.ix_(rows, r)
            self.reaction_torque[r] = -e.t[sub].sum(axis=0)
            e.t[sub] = 0.0
            e.w[sub] = self.angular_velocity[np.ix_(idx, r)]


__all__ = ["add", "LOAD", "CONSTRAINT", "ElementSelection", "Gravity", "ExternalForce", "Clamp", "PrescribedVelocity"]
