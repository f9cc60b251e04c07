"""Per-rank structure-of-arrays state: elements and bonds.

Layout convention shared by every kernel and by the parallel layer:

* element rows ``[0, n_owned)`` are owned by this rank, rows ``[n_owned, n_total)`` are ghost copies;
* every element and bond carries a global id (``gid``) that never changes during a run;
* a bond refers to its ends through local row indices ``i, j`` that are rebuilt from the end
  global ids ``gid_i, gid_j`` (``Bonds.relink``) whenever rows move (migration, ghost rebuild).

Units are SI throughout: m, kg, s, N, N m.
"""
from dataclasses import dataclass, field, fields

import numpy as np
from numba import njit

from pardem.io.checkpoint import PROPERTY_PREFIX
from pardem.physics.bond_state import BOND_BROKEN_SHEAR, BOND_BROKEN_TENSION, BOND_INTACT  # noqa: F401 (the names of Bonds.state)
from pardem.physics.quaternion import quat_to_matrix_into

# Per-element arrays that travel with an element when it migrates (f, t and rot are recomputed).
ELEMENT_FIELDS = ("x", "v", "w", "q", "radius", "mass", "inertia", "inv_mass", "inv_inertia",
                  "x0", "gid", "flags", "wall_h")
# Custom per-element arrays (``Elements.properties``, ``pardem.engine.particles``) travel in the
# ``pack`` dicts, in checkpoints and in the migration messages under ``PROPERTY_PREFIX`` plus their
# name (the prefix is the checkpoint layout's, ``pardem.io.checkpoint``).
# Per-bond arrays that travel with a bond (i, j are rebuilt from the end gids).
BOND_FIELDS = ("gid", "gid_i", "gid_j", "L0", "ka", "kb", "kt", "tau_a", "tau_b", "tau_t",
               "u1", "p1", "u2", "p2", "young", "radius", "state", "f_tensile", "f_shear", "f_yield",
               "plastic", "rot_damping")


# Element flag bits.
FLAG_NEAR_PLATE = np.uint8(1)   # touches a plate at the start: left out of the strain fit


@dataclass
class Elements:
    """Spheres with 6 degrees of freedom; arrays of shape ``[n_total, ...]``.

    x, v, w : position [m], velocity [m/s], angular velocity (world frame) [rad/s]
    q : orientation quaternion (w, x, y, z), body -> world; ``rot`` [n, 3, 3] its matrix, a
        cache refreshed on demand (``refresh_rotations``: bond creation, diagnostics), not by the
        step (the bond loop makes the matrices from ``q``)
    f, t : force [N] and torque about the centre [N m] accumulated in the current step
    radius [m], mass [kg], inertia [kg m^2] (2/5 m R^2), inv_mass, inv_inertia
    x0 : reference position of the strain fit [m]; gid : global id; flags : FLAG_* bits
    wall_h : [n, n_walls, 3] tangential force of each frictional wall on the element [N]
        (``pardem.physics.walls``); [n, 0, 3] without wall friction
    properties : {name: float64 [n] or [n, k]} custom per-element arrays (``sim.particles.
        add_property``), rows like every field (owned then ghosts); no kernel reads them, they
        travel with the element (``pack``/``unpack``) and are stored in checkpoints
    """
    x: np.ndarray
    v: np.ndarray
    w: np.ndarray
    q: np.ndarray
    rot: np.ndarray
    f: np.ndarray
    t: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    inv_mass: np.ndarray
    inv_inertia: np.ndarray
    x0: np.ndarray
    gid: np.ndarray
    flags: np.ndarray
    wall_h: np.ndarray = None
    n_owned: int = 0
    properties: dict = field(default_factory=dict)

    @property
    def n_total(self) -> int:
        return self.x.shape[0]

    @classmethod
    def from_spheres(cls, positions, radii, density, gids=None):
        """Owned elements at rest, identity orientation, from centres [n, 3] and radii [n]."""
        x = np.ascontiguousarray(positions, dtype=np.float64)
        n = x.shape[0]
        radius = np.ascontiguousarray(np.broadcast_to(radii, (n,)), dtype=np.float64).copy()
        mass = density * 4.0 / 3.0 * np.pi * radius**3
        inertia = 0.4 * mass * radius**2
        q = np.zeros((n, 4))
        q[:, 0] = 1.0
        rot = np.zeros((n, 3, 3))
        rot[:, 0, 0] = rot[:, 1, 1] = rot[:, 2, 2] = 1.0
        if gids is None:
            gids = np.arange(n, dtype=np.int64)
        return cls(x=x.copy(), v=np.zeros((n, 3)), w=np.zeros((n, 3)), q=q, rot=rot,
                   f=np.zeros((n, 3)), t=np.zeros((n, 3)), radius=radius, mass=mass,
                   inertia=inertia, inv_mass=1.0 / mass, inv_inertia=1.0 / inertia,
                   x0=x.copy(), gid=np.asarray(gids, dtype=np.int64).copy(),
                   flags=np.zeros(n, dtype=np.uint8), wall_h=np.zeros((n, 0, 3)), n_owned=n)

    def pack(self, rows):
        """Copies of the migrating fields of ``rows`` (a dict of arrays; the custom ``properties``
        under ``PROPERTY_PREFIX + name``)."""
        out = {k: getattr(self, k)[rows] for k in ELEMENT_FIELDS}
        out.update({PROPERTY_PREFIX + k: a[rows] for k, a in self.properties.items()})
        return out

    @classmethod
    def unpack(cls, parts, n_owned, copy=True):
        """Elements from a list of ``pack`` dicts; the first ``n_owned`` rows are owned.

        ``copy=False`` adopts the arrays of a single part (they must not be used elsewhere). A
        part without ``wall_h`` (a checkpoint of a run without wall friction) gets [n, 0, 3].
        """
        parts = [p if "wall_h" in p else {**p, "wall_h": np.zeros((len(p["gid"]), 0, 3))} for p in parts]
        data = _join(parts, ELEMENT_FIELDS, copy)
        # custom arrays: those of the first part (every rank holds the same names)
        props = [k for k in parts[0] if k.startswith(PROPERTY_PREFIX)] if parts else []
        extra = _join(parts, props, copy)
        n = data["x"].shape[0]
        e = cls(f=np.zeros((n, 3)), t=np.zeros((n, 3)), rot=np.empty((n, 3, 3)), n_owned=n_owned, **data,
                properties={k[len(PROPERTY_PREFIX):]: np.asarray(v, dtype=np.float64) for k, v in extra.items()})
        e.refresh_rotations()
        return e

    def owned_rows(self, keep=None, extra=None):
        """New ``Elements`` of the owned rows (those where the mask ``keep`` [n_owned] is True, all by
        default) followed by the rows of ``extra`` (an ``Elements``, all taken as owned); ghosts
        are dropped. The rows added or removed during a run (``sim.particles.add`` / ``remove``)
        pass here, then through the same migration and ghost rebuild as every row."""
        rows = np.arange(self.n_owned) if keep is None else np.nonzero(keep)[0]
        parts = [self.pack(rows)]
        if extra is not None:
            parts.append(extra.pack(slice(0, extra.n_total)))
        return Elements.unpack(parts, len(rows) + (0 if extra is None else extra.n_total))

    def permute(self, order):
        """Store the rows in the order ``order`` (int [n_total], a permutation of the rows), in
        place: every per-element array (also ``rot``, ``f``, ``t``, ``wall_h`` and the custom
        ``properties``) moves with its row. For a process without ghost rows (the owned rows are
        all the rows); whoever holds row indices (bonds: ``Bonds.relink``) must refresh them."""
        order = np.asarray(order)
        if self.n_owned != self.n_total or order.shape != (self.n_total,):
            raise ValueError(f"Elements.permute: order must hold the {self.n_total} rows of a "
                             f"process without ghosts (n_owned {self.n_owned})")
        arrays = [getattr(self, f.name) for f in fields(self) if f.name not in ("n_owned", "properties")]
        for a in arrays + list(self.properties.values()):
            if isinstance(a, np.ndarray) and a.ndim and a.shape[0] == self.n_total:
                a[...] = a[order]

    def refresh_rotations(self, start=0, stop=None):
        """Recompute the cached rotation matrices of rows ``[start, stop)`` from ``q``."""
        _refresh_rot(self.q, self.rot, start, self.n_total if stop is None else stop)

    def nbytes(self) -> int:
        return (sum(getattr(self, f.name).nbytes for f in fields(self) if f.name not in ("n_owned", "properties"))
                + sum(a.nbytes for a in self.properties.values()))


@dataclass
class Bonds:
    """Euler-Bernoulli beam bonds; arrays of shape ``[n_bonds, ...]``.

    i, j : local rows of the two ends (rebuilt from gid_i, gid_j); gid_i < gid_j always, so that
        any rank holding a bond computes it in the same orientation.
    gid : bond global id.
    L0 : length at creation [m]; ka = E S / L0 [N/m]; kb = E I [N m^2]; kt = G I0 / L0 [N m/rad].
    tau_a, tau_b, tau_t : damping time constants c/k [s] of the axial, bending and twist modes
        (``tau_b`` is read by the time-step bound only: the force loop damps the two rotation
        modes with ``rot_damping``).
    u1, p1, u2, p2 : bond axis (1 -> 2) and a reference vector normal to it at creation,
        stored in the body frame of end 1 (u1, p1) and end 2 (u2, p2).
    young [Pa], radius [m] : the bond's modulus and radius, kept for output and diagnostics.
    state : ``BOND_INTACT``, or how it broke (``BOND_BROKEN_TENSION``, ``BOND_BROKEN_SHEAR``); a
        broken bond stays in the arrays (for output and checkpoints) and exerts nothing.
    f_tensile, f_shear [N] : rupture thresholds on the axial tension ``F`` and the shear force
        ``|T|`` (strength times section S; inf = unbreakable), docs/physics.md section 7.
    f_yield [N] : densification threshold ``sigma0 S`` in compression (0 = elastic bond);
        plastic : its plastic (compressive) strain p >= 0.
    rot_damping : [n, 4] the Rayleigh damping matrix (D11, D12, D21, D22) [s] of the two end
        rotations (``pardem.physics.beam.rotation_damping_table``), constant per bond (it depends on
        the bond's constants and the mass and inertia of its ends); [n, 0] when not computed:
        undamped bonds (no memory spent), or bonds restored from a checkpoint (which does not store
        it) until ``compute_bonds`` computes it.
    damped : False when every tau is zero (the force loop then skips the damping terms).
    breakable : False when no bond can break (the loop then skips the rupture test);
    densify_p0 : the densification factor p0 of section 7 (0 = no bond densifies).
    """
    i: np.ndarray
    j: np.ndarray
    gid: np.ndarray
    gid_i: np.ndarray
    gid_j: np.ndarray
    L0: np.ndarray
    ka: np.ndarray
    kb: np.ndarray
    kt: np.ndarray
    tau_a: np.ndarray
    tau_b: np.ndarray
    tau_t: np.ndarray
    u1: np.ndarray
    p1: np.ndarray
    u2: np.ndarray
    p2: np.ndarray
    young: np.ndarray
    radius: np.ndarray
    state: np.ndarray = None
    f_tensile: np.ndarray = None
    f_shear: np.ndarray = None
    f_yield: np.ndarray = None
    plastic: np.ndarray = None
    rot_damping: np.ndarray = None
    damped: bool = True
    breakable: bool = False
    densify_p0: float = 0.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        # the inelastic fields default to an intact, unbreakable, elastic bond
        for name, value in _inelastic_defaults(self.L0.shape[0]).items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        if self.rot_damping is None:
            self.rot_damping = np.zeros((self.L0.shape[0], 0))

    def flags(self):
        """The per-run switches of the force loop (keyword arguments of ``unpack``)."""
        return {"damped": self.damped, "breakable": self.breakable, "densify_p0": self.densify_p0}

    @property
    def intact(self):
        """Mask of the bonds that still act."""
        return self.state == BOND_INTACT

    @property
    def n(self) -> int:
        return self.i.shape[0]

    def pack(self, rows):
        """Copies of the travelling fields of bonds ``rows`` (a dict of arrays)."""
        return {k: getattr(self, k)[rows] for k in BOND_FIELDS}

    @classmethod
    def unpack(cls, parts, damped, copy=True, breakable=False, densify_p0=0.0):
        """Bonds from ``pack`` dicts, duplicates (same gid) dropped, ordered by (gid_i, gid_j).

        ``i, j`` are left at -1: call ``relink`` next. ``copy=False`` adopts the arrays of a
        single part when they are already unique and ordered. Parts without the inelastic fields
        (checkpoints written before rupture existed) get intact elastic bonds. ``rot_damping`` is
        kept when every part with bonds has it, else left out ([n, 0]: ``compute_bonds``
        recomputes it, bitwise the same, from the constants and the ends' masses).
        """
        n_parts = [len(p["gid"]) for p in parts]
        parts = [{**_inelastic_defaults(n), **p} for p, n in zip(parts, n_parts)]
        widths = {_rot_damping_width(p) for p, n in zip(parts, n_parts) if n}
        width = widths.pop() if len(widths) == 1 else 0
        parts = [p if "rot_damping" in p and _rot_damping_width(p) == width
                 else {**p, "rot_damping": np.zeros((0 if width else n, width))} for p, n in zip(parts, n_parts)]
        data = _join(parts, BOND_FIELDS, copy)
        _, first = np.unique(data["gid"], return_index=True)
        keep = first[np.lexsort((data["gid_j"][first], data["gid_i"][first]))]
        if len(keep) != len(data["gid"]) or np.any(keep != np.arange(len(keep))):
            data = {k: v[keep] for k, v in data.items()}
        n = len(keep)
        return cls(i=np.full(n, -1, np.int32), j=np.full(n, -1, np.int32), damped=damped,
                   breakable=bool(breakable), densify_p0=float(densify_p0), **data)

    @classmethod
    def empty(cls):
        """No bonds (contact-only runs)."""
        parts = {k: np.zeros((0, 3) if k in ("u1", "p1", "u2", "p2") else (0, 0) if k == "rot_damping" else 0,
                             dtype=np.int64 if k.startswith("gid") else np.uint8 if k == "state"
                             else np.float64) for k in BOND_FIELDS}
        return cls.unpack([parts], damped=False)

    def counted_once(self, n_owned):
        """Mask of the bonds this rank counts in global sums and files: those whose first
        (lower-gid) end it owns. A bond held by two ranks is thus counted exactly once."""
        return self.i < n_owned

    def relink(self, element_gids):
        """Rebuild ``i, j`` from the end global ids and the rows' ``element_gids``.

        Raises KeyError naming a missing end, which means the rank lacks an element it needs.
        """
        if len(element_gids) == 0:
            if self.n:
                raise KeyError(f"bond end gid {int(self.gid_i[0])} is not held by this rank")
            return
        order = np.argsort(element_gids, kind="stable")
        sorted_g = element_gids[order]
        for ends, out in ((self.gid_i, self.i), (self.gid_j, self.j)):
            pos = np.searchsorted(sorted_g, ends)
            pos_c = np.minimum(pos, max(len(sorted_g) - 1, 0))
            bad = (pos >= len(sorted_g)) | (sorted_g[pos_c] != ends)
            if np.any(bad):
                raise KeyError(f"bond end gid {int(ends[bad][0])} is not held by this rank")
            out[:] = order[pos_c]

    def nbytes(self) -> int:
        return sum(getattr(self, f.name).nbytes for f in fields(self)
                   if isinstance(getattr(self, f.name), np.ndarray))


def _inelastic_defaults(n):
    """Inelastic fields of ``n`` intact, unbreakable, elastic bonds."""
    return {"state": np.zeros(n, np.uint8), "f_tensile": np.full(n, np.inf),
            "f_shear": np.full(n, np.inf), "f_yield": np.zeros(n), "plastic": np.zeros(n)}



def _rot_damping_width(part):
    """Columns of a ``pack`` dict's ``rot_damping`` (0 when it has none)."""
    d = part.get("rot_damping")
    return d.shape[1] if d is not None and d.ndim == 2 else 0


def _join(parts, names, copy):
    if len(parts) == 1 and not copy:
        return {k: np.ascontiguousarray(parts[0][k]) for k in names}
    return {k: np.concatenate([p[k] for p in parts]) for k in names}


@njit(cache=True, error_model="numpy")
def _refresh_rot(q, rot, start, stop):
    for k in range(start, stop):
        quat_to_matrix_into(q[k], rot[k])


@dataclass
class Plates:
    """Rigid plates normal to ``axis`` (row 0 fixed at the low end, row 1 moving at the high end),
    and optional fixed lateral walls.

    positions [m] along the axis, sides = inward normal signs (+1, -1); stiffness [N/m] of a linear
    element-plate law (kept for the critical time step); force_local = this rank's share of the force
    on each plate from the last step [N], positive in compression. The moving plate's speed rises from
    0 to ``speed`` [m/s] along a half cosine over ``ramp_time`` [s] (no velocity jump, so no stress
    wave is launched), then stays constant; its position is a closed-form function of time.
    law : ``pardem.physics.walls.Params`` of the element-wall contact (all walls); default: linear,
    frictionless, ``stiffness``. lateral : [k, 3] rows (axis, position [m], inward side) of fixed
    lateral walls (none by default). wall_force : [2 + k, 3] this rank's force on every wall [N].
    """
    axis: int
    positions: np.ndarray
    sides: np.ndarray
    stiffness: np.ndarray
    initial: np.ndarray
    force_local: np.ndarray
    speed: float = 0.0
    ramp_time: float = 0.0
    law: object = None
    lateral: np.ndarray = None
    wall_force: np.ndarray = None

    @classmethod
    def pair(cls, axis, low, high, speed, stiffness, ramp_time=0.0, law=None, lateral=()):
        """A fixed plate at ``low`` and one at ``high`` moving towards it at ``speed`` [m/s]."""
        from pardem.physics import walls
        pos = np.array([low, high], dtype=np.float64)
        if law is None:
            law = walls.Params(law="linear", kn=float(stiffness))
        lateral = np.asarray(lateral, dtype=np.float64).reshape(-1, 3)
        return cls(axis=int(axis), positions=pos, sides=np.array([1.0, -1.0]),
                   stiffness=np.full(2, float(stiffness)), initial=pos.copy(),
                   force_local=np.zeros(2), speed=float(speed), ramp_time=float(ramp_time),
                   law=law, lateral=lateral, wall_force=np.zeros((2 + len(lateral), 3)))

    @property
    def n_walls(self) -> int:
        return 2 + len(self.lateral)

    def planes(self, time):
        """``(normals [n, 3], offsets [n], velocities [n, 3])`` of every wall at ``time`` [s]
        (plates first), in the form of ``pardem.physics.walls``."""
        n = self.n_walls
        normals = np.zeros((n, 3))
        offsets = np.empty(n)
        velocities = np.zeros((n, 3))
        normals[:2, self.axis] = self.sides
        offsets[:2] = self.sides * self.positions
        velocities[:2, self.axis] = self.velocities(time)
        for k, (ax, pos, side) in enumerate(self.lateral):
            normals[2 + k, int(ax)] = side
            offsets[2 + k] = side * pos
        return normals, offsets, velocities

    def travel(self, time):
        """Distance [m] the moving plate has covered at ``time`` [s]."""
        T, v = self.ramp_time, self.speed
        if time >= T:
            return v * (time - 0.5 * T)
        return 0.5 * v * (time - T / np.pi * np.sin(np.pi * time / T))

    def time_to_travel(self, distance):
        """Inverse of ``travel`` [s]."""
        T, v = self.ramp_time, self.speed
        if distance >= 0.5 * v * T:
            return distance / v + 0.5 * T
        lo, hi = 0.0, T
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.travel(mid) < distance else (lo, mid)
        return hi

    def velocities(self, time):
        """Velocities [m/s] of the plates along the axis at ``time`` (the fixed one is 0)."""
        T, v = self.ramp_time, self.speed
        moving = v if time >= T else 0.5 * v * (1.0 - np.cos(np.pi * time / T))
        return np.array([0.0, -moving])

    def move_to(self, time):
        self.positions[1] = self.initial[1] - self.travel(time)

    def displacement(self) -> float:
        """How far the moving plate has travelled towards the fixed one [m]."""
        return float(self.initial[1] - self.positions[1])

    def gap(self) -> float:
        return float(self.positions[1] - self.positions[0])
