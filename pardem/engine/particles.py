"""Particle access by global id, the same on every rank (HOOMD-blue's snapshot and local snapshot,
LAMMPS' ``gather_atoms`` / ``scatter_atoms`` by atom id).

``sim.particles`` (a ``Particles``) reads and writes the per-particle arrays of a ``Simulation`` by
global id (gid), whatever rank owns each particle:

* global views: ``positions`` [N, 3] [m], ``velocities`` [N, 3] [m/s], ``angular_velocities``
  [N, 3] [rad/s] (world frame), ``orientations`` [N, 4] (unit quaternions ``(w, x, y, z)``, body to
  world), ``forces`` [N, 3] [N] and ``torques`` [N, 3] [N m] (of the last force evaluation, the ones
  the next step's first half kick uses), ``radii`` [N] [m], ``masses`` [N] [kg], ``gids`` [N]
  (int64). Each is a new array, the same on every rank, one row per particle in increasing gid order
  (row k holds gid k with the builders' numbering 0 .. N-1). Reading is collective (two
  ``Communicator.allgatherv``): every rank reads together. Only owned rows are gathered, so ghost
  copies never appear in them.
* ``get(name, gids)``: the rows of ``gids`` [k] only (in the order given; only those rows travel);
  ``set(name, values, gids=None)``: every rank passes the same global values ([N, ...] in gid order,
  or [k, ...] for ``gids``); each rank writes the rows it holds (owned and ghost copies), then makes
  the state consistent for the next ``sim.run`` (``set``).
* ``add_property(name, shape=(), default=0.0)``: a custom float64 array [N] or [N, k] (e.g. a
  temperature, a tracer, a grain's history), read and written by name like the built-in ones
  (``get``, ``set``, or ``sim.particles.<name>``). It lives in ``Elements.properties``: it migrates
  with its particle between ranks, ghosts copy it at every rebuild, and checkpoints
  (``pardem.save``/``load``, protocol checkpoints) store it as ``/elements/property_<name>``. No
  kernel reads it.
* ``add(positions, radii, ...)`` and ``remove(gids)``: particles added to or removed from the
  running simulation (collective; every rank passes the same arrays): new gids above the current
  largest, overlaps refused as the builder refuses them (with a count), bonds and contact
  histories of removed particles dropped, ghosts and lists rebuilt, forces recomputed as after
  ``set("positions")``; ``pardem.engine.insertion`` (``Insert``, ``Delete``) calls them during runs.
* ``local``: this rank's owned rows only (``LocalView``: views, no copy, no communication), for
  advanced use (one's own per-particle computation between runs); ghosts are never part of it.

Bad input (a name not in ``names``, a read-only name for ``set``, a wrong shape, a non-finite
value, an unknown or repeated gid) raises one ValueError naming the valid names, shape or gid
range, on every rank together.

``reduce_globals(sim)`` is the one reduction behind the global wall forces (``Walls.force``) and
the fixes' reactions (``global_reaction``, ``global_reaction_torque`` of ``Clamp`` and
``PrescribedVelocity``): ``Simulation._reduce_globals`` calls it on the steps after which an
operation may read them and at the end of every ``run``.
"""
import hashlib
import re

import numpy as np

from pardem.engine.state import Bonds

# name: (Elements field, shape after the row axis, unit)
BUILTIN = {
    "positions": ("x", (3,), "m"),
    "velocities": ("v", (3,), "m/s"),
    "angular_velocities": ("w", (3,), "rad/s"),
    "orientations": ("q", (4,), "unit quaternion w, x, y, z"),
    "forces": ("f", (3,), "N"),
    "torques": ("t", (3,), "N m"),
    "radii": ("radius", (), "m"),
    "masses": ("mass", (), "kg"),
    "gids": ("gid", (), "global id"),
}
# built-in names ``set`` may write; the others follow from the state (forces, torques) or are
# fixed at build time (radii, masses and the time step depend on them; gids identify particles)
WRITABLE = ("positions", "velocities", "angular_velocities", "orientations")
UNIT_QUATERNION_TOLERANCE = 1e-9   # | |q| - 1 | accepted by set("orientations"): round-off of a normalisation
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def _quoted(names):
    return ", ".join(repr(n) for n in names)


class LocalView:
    """This rank's owned rows ``[0, n_owned)`` of every particle array: attributes with the names
    of ``Particles.names`` (``positions`` [n, 3], ..., custom properties), as views into the
    current ``sim.elements`` arrays (no copy, no communication), and ``n`` (the owned count).

    Writing through a view changes the state without refreshing ghosts, lists or forces (``set``
    does that); a view is valid until the next step (a rebuild replaces the arrays).
    """

    def __init__(self, elements):
        self._elements = elements

    @property
    def n(self):
        return self._elements.n_owned

    def __getattr__(self, name):
        if name.startswith("_"):
            raise AttributeError(name)
        e = self._elements
        if name in BUILTIN:
            return getattr(e, BUILTIN[name][0])[:e.n_owned]
        if name in e.properties:
            return e.properties[name][:e.n_owned]
        raise AttributeError(f"no particle array {name!r}: expected one of "
                             f"{_quoted(list(BUILTIN) + sorted(e.properties))}")


class Particles:
    """Per-particle arrays of ``sim`` by global id, on every rank (module docstring).

    Holds no state of its own: ``sim.particles`` makes one on each access; the custom arrays live
    in ``sim.elements.properties``.
    """

    def __init__(self, sim):
        self._sim = sim

    # -- names ------------------------------------------------------------------------------

    @property
    def names(self):
        """Every readable name: the built-in ones, then the custom properties (sorted)."""
        return list(BUILTIN) + sorted(self._sim.elements.properties)

    @property
    def writable(self):
        """The names ``set`` accepts: positions, velocities, angular velocities, orientations and
        the custom properties."""
        return list(WRITABLE) + sorted(self._sim.elements.properties)

    def _array(self, name):
        """The ``Elements`` array (all rows) of ``name``, or ValueError naming the valid names."""
        e = self._sim.elements
        if isinstance(name, str) and name in BUILTIN:
            return getattr(e, BUILTIN[name][0])
        if isinstance(name, str) and name in e.properties:
            return e.properties[name]
        raise ValueError(f"particle array {name!r}: expected one of {_quoted(self.names)}")

    def _tail(self, name):
        return BUILTIN[name][1] if name in BUILTIN else self._sim.elements.properties[name].shape[1:]

    def __getattr__(self, name):
        # custom properties read like the built-in ones: sim.particles.temperature
        if not name.startswith("_"):
            sim = self.__dict__.get("_sim")
            if sim is not None and name in sim.elements.properties:
                return self.get(name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r} (particle arrays: "
                             f"{_quoted(self.names) if '_sim' in self.__dict__ else '?'})")

    # -- global views (collective) ----------------------------------------------------------

    @property
    def positions(self):
        """Centres [N, 3] [m], gid order, every rank (collective)."""
        return self.get("positions")

    @property
    def velocities(self):
        """Velocities [N, 3] [m/s], gid order, every rank (collective)."""
        return self.get("velocities")

    @property
    def angular_velocities(self):
        """Angular velocities (world frame) [N, 3] [rad/s], gid order, every rank (collective)."""
        return self.get("angular_velocities")

    @property
    def orientations(self):
        """Orientation quaternions ``(w, x, y, z)`` body -> world [N, 4], gid order, every rank
        (collective)."""
        return self.get("orientations")

    @property
    def forces(self):
        """Forces of the last force evaluation [N, 3] [N], gid order, every rank (collective)."""
        return self.get("forces")

    @property
    def torques(self):
        """Torques about the centres, last force evaluation [N, 3] [N m], gid order (collective)."""
        return self.get("torques")

    @property
    def radii(self):
        """Radii [N] [m], gid order, every rank (collective)."""
        return self.get("radii")

    @property
    def masses(self):
        """Masses [N] [kg], gid order, every rank (collective)."""
        return self.get("masses")

    @property
    def gids(self):
        """Global ids [N] (int64), increasing, every rank (collective)."""
        return self.get("gids")

    @property
    def n(self):
        """Number of particles N (collective)."""
        return int(self._sim.comm.sum(float(self._sim.elements.n_owned)))

    @property
    def local(self):
        """This rank's owned rows (``LocalView``; no communication)."""
        return LocalView(self._sim.elements)

    def get(self, name, gids=None):
        """Global rows of ``name`` (``names``), the same on every rank (collective).

        gids : None for every particle in increasing gid order ([N, ...]), else a 1-D sequence of
        global ids [k] (rows in that order, repeats allowed; only those rows are gathered).
        """
        arr = self._array(name)
        req = None if gids is None else _gid_array(gids, unique=False)
        sim = self._sim
        comm, e = sim.comm, sim.elements
        own = e.gid[:e.n_owned]
        mine = slice(None) if req is None else np.isin(own, req)
        g = comm.allgatherv(np.ascontiguousarray(own[mine]))
        values = comm.allgatherv(np.ascontiguousarray(arr[:e.n_owned][mine]))
        order = np.argsort(g, kind="stable")
        if req is None:
            return values[order]
        g = g[order]
        pos = _positions(g, req)
        if np.any(pos < 0):            # the same gathered gids on every rank: all raise together
            raise self._unknown(req[pos < 0], "gids")
        return values[order][pos]

    # -- writing (collective) ---------------------------------------------------------------

    def set(self, name, values, gids=None):
        """Write ``values`` into ``name`` (``writable``) by global id; collective, every rank passes
        the same ``name``, ``values`` and ``gids`` (checked: ValueError otherwise).

        values : [N, ...] in increasing gid order (``gids`` None), or [len(gids), ...] in the order
        of ``gids`` (unique global ids). Each rank writes the rows it holds, owned and ghost copies.
        Then, so that the next ``sim.run`` starts from a consistent state:

        * positions: the elements go to the ranks owning their new places, ghosts and contact
          lists are rebuilt (positions are wrapped into a periodic cell there, as at a build);
        * orientations: the cached rotation matrices are refreshed;
        * positions, velocities, angular velocities, orientations: the forces are recomputed
          (``compute_forces``, fixes included) for the first half kick, and the global wall forces
          and reactions with them. Before the first run (step 0) ``run`` computes them anyway, so a
          state set then is exactly (bit for bit) the state a builder given these values makes.
          After a run the contact and wall tangential springs keep their stored state (by gid
          pair): the increment the recomputation adds to them is undone, so that repeated sets
          do not load them again, and a pair first touching at the set starts its spring at the
          next step (a built system starts it at the first evaluation: frictional states set
          after a run are not bitwise a built system's); the bond states are those of the
          recomputed forces;
        * custom properties: nothing else (no kernel reads them).

        The strain-fit reference ``x0`` is left as it was.
        """
        if not (isinstance(name, str) and name in self.writable):
            raise ValueError(f"set: particle array {name!r} cannot be written: expected one of "
                             f"{_quoted(self.writable)} (read-only: "
                             f"{_quoted([n for n in BUILTIN if n not in WRITABLE])})")
        tail = tuple(self._tail(name))
        try:
            vals = np.array(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"set({name!r}): values must be an array of numbers of shape (n,"
                             f"{','.join(map(str, tail))}) [{_unit(name)}]") from None
        req = None if gids is None else _gid_array(gids, unique=True)
        sim = self._sim
        comm, e = sim.comm, sim.elements
        everyone = np.sort(comm.allgatherv(np.ascontiguousarray(e.gid[:e.n_owned])))
        same = comm.allgather(_digest(name, vals, req))
        if any(d != same[0] for d in same):
            raise ValueError(f"set({name!r}): the ranks passed different values or gids; every rank "
                             "must pass the same global arrays (e.g. draw random values from one seed)")
        if req is None:
            req = everyone
        else:
            pos = _positions(everyone, req)
            if np.any(pos < 0):
                raise self._unknown(req[pos < 0], "gids", everyone)
        if vals.shape != (len(req),) + tail:
            raise ValueError(f"set({name!r}): values of shape {vals.shape}, expected "
                             f"{(len(req),) + tail} (one row per {'particle, gid order' if gids is None else 'gid'}) "
                             f"[{_unit(name)}]")
        if not np.all(np.isfinite(vals)):
            raise ValueError(f"set({name!r}): values must be finite [{_unit(name)}]")
        if name == "orientations":
            bad = np.abs(np.linalg.norm(vals, axis=1) - 1.0) > UNIT_QUATERNION_TOLERANCE
            if np.any(bad):
                k = int(np.argmax(bad))
                raise ValueError(f"set('orientations'): row {k} = {vals[k].tolist()} is not a unit "
                                 f"quaternion (| |q| - 1 | <= {UNIT_QUATERNION_TOLERANCE:g})")
        arr = self._array(name)
        order = np.argsort(req, kind="stable")
        pos = _positions(req[order], e.gid)     # every held row, ghosts included
        rows = np.nonzero(pos >= 0)[0]
        arr[rows] = vals[order[pos[rows]]]
        if name not in BUILTIN:
            return
        if name == "orientations":
            e.refresh_rotations()
        if name == "positions":
            _rebuild(sim)
        _recompute_forces(sim)

    # -- adding and removing particles (collective) -----------------------------------------

    def add(self, positions, radii, velocities=None, angular_velocities=None, properties=None,
            allow_overlaps=False):
        """Add particles to the running simulation and return their global ids [k] (int64):
        ``max(gids) + 1`` upwards, in the order given. Collective: every rank passes the same arrays
        (checked: ValueError otherwise).

        positions [k, 3] [m] (or [k, 2] in 2D), radii [k] or scalar [m] (the grains' density is
        the system's), velocities [k, 3] [m/s] and angular_velocities [k, 3] [rad/s] (default at
        rest), properties ``{name: [k] or [k, m]}`` values of the custom arrays (``add_property``;
        those not given start at 0). Refused (one ValueError, before any change) like the
        builder's input (``pardem.engine.inputs.check_overlaps``): a new centre coinciding with
        another particle's, or (unless ``allow_overlaps``) a new particle overlapping a new or an
        existing one by more than half the smaller radius, with the count of such pairs; a radius
        whose critical time step (contact law, walls) is below ``sim.dt``. A radius above every
        radius so far widens the contact reach and the ghost range (stored in checkpoints).

        Then the rows go to the ranks owning their places, ghosts and contact lists are rebuilt,
        and the forces are recomputed as after ``set("positions")``; the other particles keep their
        state, contact histories and bonds.
        """
        from pardem.engine import inputs
        from pardem.engine.plane import dimension_of, in_plane
        from pardem.engine.state import Elements
        sim = self._sim
        comm, e = sim.comm, sim.elements
        dim = dimension_of(sim)
        if np.size(positions) == 0:
            return np.zeros(0, np.int64)
        x = inputs.check_positions(positions, dim, "add: positions")
        k = len(x)
        r = inputs.check_radii(radii, k, "add: radii")
        v = inputs.check_vectors(velocities, k, "add: velocities", "[m/s]", dimension=dim)
        w = inputs.check_vectors(angular_velocities, k, "add: angular_velocities", "[rad/s]", dimension=dim)
        if dim == 2:
            v = in_plane(v, (2,), "add: velocities")
            w = in_plane(w, (0, 1), "add: angular_velocities")
        props = self._new_properties(properties, k)
        digest = _digest("add", np.concatenate([x.ravel(), r, np.zeros(0) if v is None else v.ravel(),
                                                np.zeros(0) if w is None else w.ravel()]
                                               + [props[n].ravel() for n in sorted(props)]), None)
        if any(d != digest for d in comm.allgather(digest)):
            raise ValueError("add: the ranks passed different particles; every rank must pass the same "
                             "global arrays (e.g. draw them from one seed)")
        if not isinstance(allow_overlaps, (bool, np.bool_)):
            raise ValueError(f"add: allow_overlaps must be True or False, got {allow_overlaps!r}")
        x_old, r_old = self.positions, self.radii
        cell = sim.cell
        box = {} if cell is None else {"box_lo": cell.lo, "box_length": cell.length, "periodic": cell.periodic}
        deepest = np.inf if allow_overlaps else inputs.MAX_OVERLAP
        try:
            inputs.check_overlaps(x, r, max_overlap=deepest, **box)
        except ValueError as err:
            raise ValueError(f"add: new particles: {err}") from None
        _check_overlaps_with(x, r, x_old, r_old, deepest, box)
        r_all = max(float(r.max()), float(r_old.max()) if len(r_old) else 0.0)
        _check_step(sim, r, r_all)
        g0 = int(comm.max(float(e.gid[:e.n_owned].max()) if e.n_owned else -1.0)) + 1
        gids = g0 + np.arange(k, dtype=np.int64)
        _widen_reach(sim, r_all)
        extra = None
        if comm.rank == 0:        # the migration takes every row to its owner
            extra = Elements.from_spheres(x, r, sim.density, gids)
            if v is not None:
                extra.v[:] = v
            if w is not None:
                extra.w[:] = w
            extra.wall_h = np.zeros((k,) + e.wall_h.shape[1:])
            extra.properties = props
        else:
            extra = Elements.from_spheres(np.zeros((0, 3)), np.zeros(0), sim.density, np.zeros(0, np.int64))
            extra.wall_h = np.zeros((0,) + e.wall_h.shape[1:])
            extra.properties = {n: a[:0] for n, a in props.items()}
        sim.elements = e.owned_rows(extra=extra)
        _rows_changed(sim)
        sim.n_elements = (sim.n_elements or 0) + k
        _recompute_forces(sim)
        return gids

    def remove(self, gids):
        """Remove the particles of global ids ``gids`` [k] (unique; every rank passes the same),
        with their bonds and their contact histories; the others keep their gids and state.
        Collective. The forces are then recomputed as after ``set("positions")``. ValueError for an
        unknown gid, or for removing every particle."""
        from pardem.engine.state import Bonds
        req = _gid_array(gids, unique=True)
        sim = self._sim
        comm, e = sim.comm, sim.elements
        same = comm.allgather(_digest("remove", np.zeros(0), req))
        if any(d != same[0] for d in same):
            raise ValueError("remove: the ranks passed different gids; every rank must pass the same")
        everyone = np.sort(comm.allgatherv(np.ascontiguousarray(e.gid[:e.n_owned])))
        pos = _positions(everyone, req)
        if np.any(pos < 0):
            raise self._unknown(req[pos < 0], "remove: gids", everyone)
        if len(req) == 0:
            return
        if len(req) == len(everyone):
            raise ValueError(f"remove: gids name all {len(everyone)} particles; a simulation keeps at least one")
        b = sim.bonds
        if b is not None and b.n:
            keep_b = ~(np.isin(b.gid_i, req) | np.isin(b.gid_j, req))
            if not np.all(keep_b):
                sim.bonds = Bonds.unpack([b.pack(keep_b)], **b.flags())
        sim.elements = e.owned_rows(keep=~np.isin(e.gid[:e.n_owned], req))
        _rows_changed(sim)
        sim.n_elements = (sim.n_elements or len(everyone)) - len(req)
        _recompute_forces(sim)

    def _new_properties(self, given, k):
        """The custom arrays of ``k`` new rows: ``given[name]`` or zeros, every custom name."""
        have = self._sim.elements.properties
        given = {} if given is None else given
        if not isinstance(given, dict) or any(n not in have for n in given):
            raise ValueError(f"add: properties must be a dict of custom arrays among "
                             f"{_quoted(sorted(have)) or 'none (add_property first)'}, got {given!r:.80}")
        out = {}
        for name, a in have.items():
            tail = a.shape[1:]
            vals = np.zeros((k,) + tail) if name not in given else np.array(given[name], dtype=np.float64)
            if vals.shape != (k,) + tail or not np.all(np.isfinite(vals)):
                raise ValueError(f"add: properties[{name!r}] must be finite of shape {(k,) + tail}, got "
                                 f"shape {vals.shape}")
            out[name] = np.ascontiguousarray(vals)
        return out

    # -- custom arrays ----------------------------------------------------------------------

    def add_property(self, name, shape=(), default=0.0):
        """Add a custom per-particle float64 array ``name`` of shape [N] (``shape=()``) or [N, k]
        (``shape=(k,)``), every row ``default`` (a number, or an array of ``shape``). Every rank
        calls it (no communication). ValueError for a taken or malformed name or a bad shape."""
        e = self._sim.elements
        if not isinstance(name, str) or not _NAME.match(name):
            raise ValueError(f"add_property: name {name!r} must be an identifier (letters, digits, _)")
        if name in BUILTIN or name in e.properties or hasattr(type(self), name):
            raise ValueError(f"add_property: name {name!r} is taken; taken names: "
                             f"{_quoted(self.names)}")
        shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
        if not (shape == () or (len(shape) == 1 and isinstance(shape[0], (int, np.integer))
                                 and not isinstance(shape[0], bool) and shape[0] >= 1)):
            raise ValueError(f"add_property({name!r}): shape must be () or (k,) with k >= 1, got {shape!r}")
        try:
            fill = np.broadcast_to(np.asarray(default, dtype=np.float64), shape)
        except (TypeError, ValueError):
            raise ValueError(f"add_property({name!r}): default must be a number or an array of shape "
                             f"{shape}, got {default!r}") from None
        if not np.all(np.isfinite(fill)):
            raise ValueError(f"add_property({name!r}): default must be finite, got {default!r}")
        e.properties[name] = np.ascontiguousarray(np.broadcast_to(fill, (e.n_total,) + shape), dtype=np.float64).copy()

    def remove_property(self, name):
        """Drop the custom array ``name`` (every rank)."""
        if name not in self._sim.elements.properties:
            raise ValueError(f"remove_property: no custom array {name!r}; custom arrays: "
                             f"{_quoted(sorted(self._sim.elements.properties)) or 'none'}")
        del self._sim.elements.properties[name]

    # -- errors -----------------------------------------------------------------------------

    def _unknown(self, missing, what, everyone=None):
        """ValueError naming unknown gids and the valid ones (collective when ``everyone`` is None:
        called on every rank together)."""
        if everyone is None:
            e = self._sim.elements
            everyone = self._sim.comm.allgatherv(np.ascontiguousarray(e.gid[:e.n_owned]))
        n = len(everyone)
        lo, hi = (int(everyone.min()), int(everyone.max())) if n else (0, -1)
        valid = f"{lo} .. {hi}" if hi - lo + 1 == n else f"{n} ids between {lo} and {hi}"
        shown = ", ".join(str(int(g)) for g in missing[:5]) + (" ..." if len(missing) > 5 else "")
        return ValueError(f"{what} {shown}: not a particle of this simulation; valid global ids: "
                          f"{valid} ({n} particles)")


def _unit(name):
    return BUILTIN[name][2] if name in BUILTIN else "user units"


def _gid_array(gids, unique):
    """``gids`` as a 1-D int64 array, or ValueError (integers >= 0; ``unique``: no repeats)."""
    arr = np.asarray(gids)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim != 1:
        raise ValueError(f"gids must be a 1-D sequence of global ids, got shape {arr.shape}")
    if arr.size == 0:
        return np.zeros(0, np.int64)
    if arr.dtype.kind not in "iu":
        if not (arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))):
            raise ValueError(f"gids must be integer global ids, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    if np.any(arr < 0):
        raise ValueError(f"gids must be >= 0 (global ids), got {int(arr.min())}")
    if unique and len(np.unique(arr)) != len(arr):
        raise ValueError(f"gids must not repeat a particle: {len(arr)} ids, {len(np.unique(arr))} distinct")
    return arr


def _positions(sorted_gids, wanted):
    """Index of each of ``wanted`` in the increasing ``sorted_gids``, -1 where absent."""
    if len(sorted_gids) == 0:
        return np.full(len(wanted), -1, np.int64)
    pos = np.searchsorted(sorted_gids, wanted)
    pos_c = np.minimum(pos, len(sorted_gids) - 1)
    return np.where(sorted_gids[pos_c] == wanted, pos_c, -1).astype(np.int64)


def _digest(name, values, gids):
    h = hashlib.sha256(name.encode())
    h.update(repr(values.shape).encode())
    h.update(np.ascontiguousarray(values).tobytes())
    if gids is not None:
        h.update(gids.tobytes())
    return h.hexdigest()[:32]


def _rebuild(sim):
    """After positions changed: migration, ghosts and contact list, as a builder makes them."""
    if sim.domain is not None:
        bonds = sim.bonds if sim.bonds is not None else Bonds.empty()
        if sim.contacts is None:
            e, b = sim.domain.setup(sim.elements, bonds)
        else:
            e, b, table = sim.domain.setup_with_pairs(sim.elements, bonds, sim.contacts.table())
            sim.contacts.rebuild(e, b, table)
            sim.pairs_freed = False
        sim.elements = e
        if sim.bonds is not None:
            sim.bonds = b
    elif sim.contacts is not None:
        sim.rebuild_contacts()


def _check_overlaps_with(x, r, x_old, r_old, deepest, box):
    """ValueError (on every rank: same inputs) if a new sphere's centre coincides with an existing
    one's, or it overlaps one by more than ``deepest`` of the smaller radius (the builder's bounds,
    ``pardem.engine.inputs``); with the count and the first pair."""
    from pardem.domains.packing import overlaps
    from pardem.engine.inputs import COINCIDENT
    i, j, depth = overlaps(x, r, x_old, r_old, **box)
    small = np.minimum(r[i], r_old[j])
    dist = r[i] + r_old[j] - depth
    for bad, what in ((dist < COINCIDENT * small, f"coincide with (centres closer than {COINCIDENT:g} of the "
                                                  "smaller radius)"),
                      (depth > deepest * small, f"overlap by more than {deepest:g} of the smaller radius")):
        if np.any(bad):
            m = int(np.argmax(bad))
            raise ValueError(f"add: {int(bad.sum())} pair(s) of a new and an existing particle {what}; first: "
                             f"new particle {int(i[m])} (radius {r[i[m]]:.4g} m) and the particle of row {int(j[m])} "
                             f"in gid order (radius {r_old[j[m]]:.4g} m), overlap {depth[m]:.4g} m; "
                             "insert where there is room (pardem.random_pack with existing=...)")


def _check_step(sim, r, r_all):
    """ValueError when ``sim.dt`` is above the critical step of new radii ``r`` [k] [m] (contact law;
    walls at the stiffness of the largest radius ``r_all`` [m] on the lightest grain); lowers
    ``sim.dt_critical`` to it."""
    from pardem.engine.critical_step import contact_law_name
    from pardem.physics.contact_laws import critical_time_step
    from pardem.physics.timestep import critical_time_step as verlet_step
    from pardem.physics.timestep import max_tau
    comm, e = sim.comm, sim.elements
    dt_c = np.inf
    if sim.contacts is not None:
        dt_c = critical_time_step(contact_law_name(sim.contacts), sim.contacts.params, np.asarray(r), sim.density)
    if callable(getattr(sim.plates, "stiffness", None)):
        m_new = sim.density * 4.0 / 3.0 * np.pi * float(r.min()) ** 3
        m_min = min(m_new, float(comm.min(float(e.mass[:e.n_owned].min()) if e.n_owned else np.inf)))
        tau = float(comm.max(max_tau(sim.bonds if sim.bonds is not None else Bonds.empty())))
        dt_c = min(dt_c, verlet_step(sim.plates.stiffness(r_all) / m_min, tau))
    if not sim.dt <= dt_c:
        raise ValueError(f"add: radii down to {float(r.min()):.4g} m have a critical time step {dt_c:.6g} s below "
                         f"sim.dt = {sim.dt:.6g} s: expected radii whose critical step is >= dt")
    if sim.dt_critical is not None:
        sim.dt_critical = float(min(sim.dt_critical, dt_c))


def _widen_reach(sim, r_all):
    """Contact reach ``2 R_max + skin`` and ghost range for the largest radius ``r_all`` [m]."""
    if sim.contacts is None or sim.reach is None:
        return
    reach = 2.0 * r_all + sim.contacts.skin
    if reach <= sim.reach:
        return
    if sim.cell is not None:
        from pardem.engine.contacts import check_period
        try:
            check_period(sim.cell, reach)
        except ValueError as err:
            raise ValueError(f"add: radius {r_all:.4g} m: {err}") from None
    sim.reach = reach
    if sim.contacts.cut > 0.0:
        sim.contacts.cut = reach
    sim.ghost_range = max(sim.ghost_range or 0.0, reach)
    if sim.domain is not None:
        sim.domain.ghost_range = max(sim.domain.ghost_range, reach)


def _rows_changed(sim):
    """After rows were added or removed (owned rows only, ghosts dropped): migration, ghosts, bond
    links and the contact list."""
    if sim.domain is not None:
        _rebuild(sim)
        return
    if sim.bonds is not None:
        sim.bonds.relink(sim.elements.gid)
    if sim.contacts is not None:
        sim.rebuild_contacts()     # wraps into the cell
    elif sim.cell is not None:
        sim.cell.wrap(sim.elements)


def _recompute_forces(sim):
    """The forces of the current state for the next first half kick (after a run; at step 0
    ``Simulation.run`` computes them), the tangential springs kept as stored."""
    if sim.step_count == 0:
        sim.initial_forces = False     # the next run computes them from the new state
        return
    e = sim.elements
    e.f[:] = 0.0
    e.t[:] = 0.0
    kept = [e.wall_h.copy()]
    if sim.contacts is not None:
        kept.append(sim.contacts.history.copy())
    sim.compute_forces()
    e.wall_h[...] = kept[0]
    if sim.contacts is not None:
        sim.contacts.history[...] = kept[1]
    reduce_globals(sim)


def reduce_globals(sim):
    """The global wall forces (``Walls.force`` [n_walls, 3] [N]) and the fixes' reactions
    (``global_reaction``, ``global_reaction_torque`` [3] of every fix of ``sim.fixes`` that has
    them) from this rank's shares of the last force evaluation: one allreduce of a small vector
    (a float sum: decompositions agree to its round-off). Collective; nothing is communicated when
    there are neither walls nor such fixes (the same on every rank)."""
    from pardem.engine.walls import Walls
    walls = sim.plates if isinstance(sim.plates, Walls) else None
    fixes = [f for f in sim.fixes if hasattr(f, "global_reaction")]
    if walls is None and not fixes:
        return
    parts = [walls.wall_force.ravel()] if walls is not None else []
    parts += [np.concatenate([f.reaction, f.reaction_torque]) for f in fixes]
    total = np.asarray(sim.comm.sum(np.concatenate(parts)))
    k = 0
    if walls is not None:
        k = walls.wall_force.size
        walls.force[:] = total[:k].reshape(walls.force.shape)
    for f in fixes:
        f.global_reaction[:] = total[k:k + 3]
        f.global_reaction_torque[:] = total[k + 3:k + 6]
        k += 6


__all__ = ["Particles", "LocalView", "reduce_globals", "BUILTIN", "WRITABLE"]
