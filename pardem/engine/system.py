"""The description of a system and the one builder that makes a ``Simulation`` of it.

A ``System`` says what is simulated, as plain values: the particles (global arrays: centres, radii,
density, initial velocities), the contact model (a law of ``pardem.physics.contact_laws`` and its
parameters), the bond model (beam bonds: ``BeamMaterial``, the bonded pairs, the material frame),
planar walls, a periodic cell, the integration (time step, damping, stability limit) and the
decomposition over ranks (slab axis, skin, load balance). ``build(comm, system)`` makes the
``Simulation`` on every rank (every rank passes the same description); element ``k`` of the arrays
gets global id ``k``.

The model part of a description (everything but the particle arrays and the bonded pairs) is
serialisable (``System.to_dict`` / ``System.from_dict``, JSON-able); ``describe(sim)`` gives the
model of a running simulation (its current contact parameters, damping, time step, walls and cell),
which every checkpoint stores and every restore reads (``pardem.restart``): one description, one
builder, one restore.

Example: a sphere dropped on a floor::

    system = System(Particles([[0, 0, 0.02]], 0.01, 2500.0),
                    walls=WallModel(normals=[[0, 0, 1]], points=[[0, 0, 0]],
                                    law=wall_law("linear", stiffness=1e5)))
    sim = build(Communicator(), system)
"""
import math
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from pardem.engine import inputs
from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.engine.contacts import Contacts, check_period
from pardem.engine.critical_step import contact_law_name, critical_time_step_of
from pardem.engine.periodic_cell import PeriodicCell
from pardem.engine.plane import PlaneConstraint, check_dimension, in_plane, plane_of
from pardem.engine.simulation import Simulation
from pardem.engine.state import Bonds, Elements
from pardem.engine.walls import Walls, add_walls, attach_servos, check_servos
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import Slabs, choose_axis
from pardem.physics import walls as wall_kernels
from pardem.physics.contact_laws import LAWS, critical_time_step, law_params
from pardem.physics.contact_laws import law as contact_law

GHOST_STRETCH = 1.25   # bonds may stretch by 25 % before they outgrow the ghost layer
SKIN_RADII = 0.2       # default skin [mean radii]


# -- the parts of a description ---------------------------------------------------------------

@dataclass
class Particles:
    """The spheres at the start (global arrays, the same on every rank).

    positions [n, 3] [m] (or [n, 2] in 2D); radii [n] or scalar [m]; density [kg/m^3];
    velocities [n, 3] [m/s] and angular_velocities [n, 3] [rad/s] (default at rest).
    allow_overlaps : accept unbonded spheres overlapping by more than half the smaller radius (a
    random gas a servo or a relaxation will pull apart; coincident centres are refused anyway).
    gids : [n] increasing integers in [0, 2^31), the particles' global ids (default 0 .. n-1): a
    case rebuilt from another keeps its grains' ids (``regrown``).
    """
    positions: object
    radii: object
    density: float
    velocities: object = None
    angular_velocities: object = None
    allow_overlaps: bool = False
    gids: object = None


@dataclass
class ContactModel:
    """Element-element contacts: ``law`` a name of ``pardem.physics.contact_laws.LAWS``
    (``"hertz_mindlin"``, ``"linear"``, ``"hertz_mindlin_rolling"``), ``params`` its parameters
    (dict of the law's ``Params`` keywords, SI units). ``resolve``: instead of ``params``, a function ``(comm, elements, bonds) ->
    params`` called once by the builder after the bonds are made, for parameters derived from them
    (a deck's "auto" contact modulus: the bonds' largest); the built system holds its result."""
    law: str = "hertz_mindlin"
    params: dict = field(default_factory=dict)
    resolve: object = None

    def law_params(self):
        """The validated ``Params`` of the law."""
        return law_params(self.law, self.params)


@dataclass
class BondModel:
    """Euler-Bernoulli beam bonds (``pardem.physics.beam``).

    material : ``BeamMaterial``; pairs [b, 2] : indices of the bonded particles (any order, each bond
    once; bond ``k`` gets global id ``k`` in sorted order); frame [3, 3] : the LRT material frame,
    rows the L, R, T axes in world coordinates (default identity). An anisotropic material gives each
    bond the value its direction takes in this frame by ``material.law``.
    """
    material: BeamMaterial
    pairs: object = None
    frame: object = None


@dataclass
class WallModel:
    """Planar walls (``pardem.engine.walls``): inward normals [w, 3], a point on each [w, 3] [m],
    translation velocities [3] or [w, 3] [m/s] (default static), one element-wall ``law``
    (``pardem.physics.walls.Params``, e.g. from ``pardem.engine.walls.wall_law``).
    ``time0`` [s]: the time at which the walls pass through ``points``. ``offsets`` [w] [m]: the
    exact plane offsets ``n . x`` at ``time0`` with ``normals`` already unit (``describe`` sets it,
    so that a restored wall is the same bits; default from ``points``).
    ``motions``: one per plane, None (the constant velocity), a motion of
    ``pardem.physics.wall_motion`` (``Constant``, ``Ramp``, ``Sinusoid``, ``Table``) or a
    force-controlled ``pardem.engine.walls.Servo`` (or their dicts); ``cylinders``: a list of
    ``pardem.engine.walls.Cylinder``; ``meshes``: a list of ``pardem.engine.walls.Mesh``
    (triangles from ``pardem.read_stl``). ``normals`` and ``points`` may be empty ([0, 3]) when
    there are cylinders or meshes."""
    normals: object
    points: object
    law: wall_kernels.Params
    velocities: object = None
    time0: float = 0.0
    offsets: object = None
    motions: object = None
    cylinders: object = None
    meshes: object = None

    def make(self):
        """The ``Walls`` of this model (not attached to a simulation)."""
        return self.exact(Walls(self.normals, self.points, self.law, self.velocities, time0=self.time0,
                                motions=_copies(self.motions), cylinders=_copies(self.cylinders),
                                meshes=_copies(self.meshes)))

    def exact(self, walls):
        """Give ``walls`` (built from this model) the stored unit normals and offsets bit for bit."""
        if self.offsets is not None:
            walls.normals = np.ascontiguousarray(np.reshape(self.normals, (-1, 3)), dtype=np.float64)
            walls.offsets0 = np.asarray(self.offsets, dtype=np.float64).copy()
        walls.time0 = float(self.time0)
        return walls


@dataclass
class Cell:
    """A box ``lo`` [3] [m] with edges ``length`` [3] [m], periodic along ``periodic`` [3]; a
    diagonal strain ``rate`` [3] [1/s] or a pressure ``servo`` (``(p0 [Pa], gain [1/(Pa s)],
    max_rate [1/s])`` or the dict of ``PeriodicCell.triaxial_servo`` or ``normal_servo``). In 2D the
    z edge is the thickness of the stress convention (``thickness`` [m], default the mean diameter).
    ``shear_rate`` [3] [1/s]: simple shear, the off-diagonal velocity gradient ``(dv_x/dy, dv_x/dz,
    dv_y/dz)`` (the cell tilts, LAMMPS' triclinic box; docs/physics.md section 12; the cell starts
    rectangular); slabs are then cut along an axis the shear does not move (y or z for xy).
    ``state``: the full state of a running cell (``PeriodicCell.state``, with its tilt), set by
    ``describe``."""
    lo: object = (0.0, 0.0, 0.0)
    length: object = (1.0, 1.0, 1.0)
    periodic: object = (True, True, True)
    rate: object = (0.0, 0.0, 0.0)
    servo: object = None
    thickness: object = None
    state: dict = None
    shear_rate: object = (0.0, 0.0, 0.0)


@dataclass
class Integration:
    """Velocity Verlet settings.

    dt [s] : the time step (None: ``dt_fraction`` of the critical step; a dt above the critical
    step is refused); viscous_damping [1/s] : global drag ``-C m v``, ``-C I w``; max_speed [m/s] :
    speed above which the run is declared unstable; max_step_displacement : the largest
    displacement of an element in one step, as a fraction of the smallest radius, beyond which the
    run is a runaway (``Simulation.speed_limit``; raise it for a stage that is violent on purpose,
    such as a random gas with deep overlaps pushed apart); check_every [steps] : stability
    checks; orientation : integrate the orientations (False for granular runs nothing reads them
    in; bonds need them).
    """
    dt: float = None
    dt_fraction: float = 0.3
    viscous_damping: float = 0.0
    max_speed: float = 1e4
    max_step_displacement: float = 0.1
    check_every: int = 50
    orientation: bool = True


@dataclass
class Decomposition:
    """How the system is cut over ranks (slabs along one axis, ``pardem.parallel.slabs``).

    slab_axis : 0, 1, 2 or "auto" (the longest extent); skin [m] : neighbour-list and ghost skin
    (None: 0.2 mean radius); balance_every [steps] : load-balance checks (0: never);
    balance_threshold : relative imbalance that moves the cuts; balance_by : "count" or "time";
    initial_split : "balanced" (equal counts) or the fractions of the elements below each of the
    ``ranks - 1`` first cuts.
    """
    slab_axis: object = "auto"
    skin: float = None
    balance_every: int = 0
    balance_threshold: float = 0.05
    balance_by: str = "count"
    initial_split: object = "balanced"


@dataclass
class System:
    """Everything a ``Simulation`` is made from (module docstring). ``dimension`` 3, or 2 for disks
    in the plane z = 0 (``pardem.engine.plane``: the cell periodic in x, y at most, walls lines of
    the plane)."""
    particles: Particles = None
    contacts: ContactModel = None
    bonds: BondModel = None
    walls: WallModel = None
    cell: Cell = None
    integration: Integration = field(default_factory=Integration)
    decomposition: Decomposition = field(default_factory=Decomposition)
    dimension: int = 3

    def to_dict(self):
        """The model (no particle arrays, no bonded pairs) as a JSON-able dict."""
        bonds = None
        if self.bonds is not None:
            frame = None if self.bonds.frame is None else np.asarray(self.bonds.frame, dtype=float).tolist()
            bonds = {"material": _jsonable(asdict(self.bonds.material)), "frame": frame}
        walls = None
        if self.walls is not None:
            w = self.walls
            walls = {"normals": _jsonable(w.normals), "points": _jsonable(w.points),
                     "velocities": _jsonable(w.velocities), "time0": float(w.time0),
                     "offsets": _jsonable(w.offsets), "law": _init_fields(w.law)}
            # the new kinds only when present: older descriptions keep their exact dict
            for name in ("motions", "cylinders", "meshes"):
                items = getattr(w, name)
                if items is not None and len(items):
                    walls[name] = [None if m is None else (m if isinstance(m, dict) else m.to_dict())
                                   for m in items]
        cell = None if self.cell is None else {f.name: _jsonable(getattr(self.cell, f.name))
                                               for f in fields(self.cell)}
        return {"kind": "system", "dimension": int(self.dimension),
                "contacts": None if self.contacts is None else {"law": self.contacts.law,
                                                                "params": _jsonable(self.contacts.params)},
                "bonds": bonds, "walls": walls, "cell": cell,
                "integration": _jsonable(asdict(self.integration)),
                "decomposition": _jsonable(asdict(self.decomposition))}

    @classmethod
    def from_dict(cls, d, particles=None):
        """The description of ``to_dict`` (with ``particles``, or none)."""
        if not isinstance(d, dict) or d.get("kind") != "system":
            raise ValueError("not a system description (expected the dict of System.to_dict)")
        bonds = None
        if d.get("bonds") is not None:
            m = {k: tuple(v) if isinstance(v, list) else v for k, v in d["bonds"]["material"].items()}
            bonds = BondModel(BeamMaterial(**m), frame=d["bonds"]["frame"])
        walls = None
        if d.get("walls") is not None:
            w = d["walls"]
            walls = WallModel(w["normals"], w["points"], wall_kernels.Params(**w["law"]), w["velocities"],
                              w["time0"], w.get("offsets"), w.get("motions"), w.get("cylinders"),
                              w.get("meshes"))
        ct = d.get("contacts")
        return cls(particles=particles,
                   contacts=None if ct is None else ContactModel(ct["law"], dict(ct["params"])),
                   bonds=bonds, walls=walls, cell=None if d.get("cell") is None else Cell(**d["cell"]),
                   integration=Integration(**d["integration"]),
                   decomposition=Decomposition(**d["decomposition"]), dimension=int(d["dimension"]))


def _copies(items):
    """Fresh wall parts from a model's list (dicts or objects: a servo's state is per run)."""
    if items is None or not len(items):
        return None
    return [None if m is None else (m if isinstance(m, dict) else m.to_dict()) for m in items]


def _described(items):
    """A running wall set's list as dicts (None when empty or all None: older descriptions)."""
    if not items or all(m is None for m in items):
        return None
    return [None if m is None else m.to_dict() for m in items]


def _init_fields(params):
    """The constructor arguments of a parameter dataclass (derived fields left out), JSON-able."""
    return {f.name: _jsonable(getattr(params, f.name)) for f in fields(params) if f.init}


def _jsonable(value):
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _positive(value, name, unit):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0 {unit}, got {value!r}")
    return float(value)


def _gids(gids, n):
    """``Particles.gids`` checked: [n] strictly increasing integers in [0, 2^31) (int64)."""
    g = np.asarray(gids)
    if g.shape != (n,) or (n and not np.issubdtype(g.dtype, np.integer)):
        raise ValueError(f"Particles.gids must be [{n}] integers (one per particle), got shape {g.shape} "
                         f"of {g.dtype}")
    g = g.astype(np.int64)
    if n and (g[0] < 0 or g[-1] >= 1 << 31 or np.any(np.diff(g) <= 0)):
        raise ValueError("Particles.gids must be strictly increasing integers in [0, 2^31)")
    return g


def _skin(dec, radii):
    """The neighbour-list and ghost skin [m]: the decomposition's, or 0.2 mean radius."""
    if dec.skin is None:
        return SKIN_RADII * float(radii.mean())
    return _positive(dec.skin, "Decomposition.skin", "[m] (or None: 0.2 mean radius)")


# -- the builder ----------------------------------------------------------------------------

def build(comm, system):
    """The ``Simulation`` of ``system`` on this rank (collective; every rank passes the same).

    Rank r keeps the elements of its slab (cuts balancing the counts) and the partners of their
    bonds; the slab layer (``pardem.parallel.slab_comm.SlabComm``) builds the ghosts. The time step is
    checked against the critical step of velocity Verlet (``critical_time_step``). ValueError (one
    line naming the argument and its allowed range) for bad input, before any work. ``sim.system``
    is the description with the values the builder chose (dt, skin, slab axis) and without the
    particle arrays.
    """
    if not isinstance(system, System):
        raise ValueError(f"system must be a pardem System, got {type(system).__name__}")
    dim = check_dimension(system.dimension, "System.dimension")
    p = system.particles
    if not isinstance(p, Particles):
        raise ValueError(f"System.particles must be a pardem Particles, got {type(p).__name__}")
    integ, dec = system.integration, system.decomposition
    x, r, density = _particle_arrays(p, dim)
    n = len(x)
    v0 = inputs.check_vectors(p.velocities, n, "Particles.velocities", "[m/s]")
    w0 = inputs.check_vectors(p.angular_velocities, n, "Particles.angular_velocities", "[rad/s]")
    if dim == 2:
        v0 = in_plane(v0, (2,), "Particles.velocities")
        w0 = in_plane(w0, (0, 1), "Particles.angular_velocities")
    cell = _cell(system.cell, r, dim)
    if cell is not None:
        # slabs are cut in the cell's frame
        lo0, edge = cell.lo, cell.length
        x = np.where(cell.periodic, lo0 + np.mod(x - lo0, edge), x)
        if cell.tilted:
            raise ValueError("System.cell: a tilted cell is restored from its state only (Cell.state, "
                             "restart.load); a new cell starts rectangular, Cell.shear_rate tilts it")
    pairs, material, frame = _bond_model(system.bonds, n)
    # coincident centres, or unbonded spheres overlapping by more than half the smaller radius
    # (minimum images in a periodic cell), are refused before any work
    if not isinstance(p.allow_overlaps, (bool, np.bool_)):
        raise ValueError(f"Particles.allow_overlaps must be True or False, got {p.allow_overlaps!r}")
    deepest = math.inf if p.allow_overlaps else inputs.MAX_OVERLAP
    if cell is None:
        inputs.check_overlaps(x, r, pairs, max_overlap=deepest)
    else:
        if system.contacts is not None:
            check_period(cell, 2.0 * float(r.max()) + _skin(dec, r))
        inputs.check_overlaps(x, r, pairs, cell.lo, cell.length, cell.periodic, max_overlap=deepest)
    if len(pairs) and cell is not None and np.any(cell.periodic):
        raise ValueError("System.bonds with a periodic Cell: bonds across a periodic boundary are not "
                         "supported; expected a cell without periodic axes, or no bonds")
    prm = None
    model = system.contacts
    if model is not None:
        if not isinstance(model, ContactModel):
            raise ValueError(f"System.contacts must be a ContactModel, got {type(model).__name__}")
        if model.resolve is None:
            prm = model.law_params()
        elif not callable(model.resolve):
            raise ValueError(f"ContactModel.resolve must be a function (comm, elements, bonds) -> params, "
                             f"got {type(model.resolve).__name__}")
        else:
            contact_law(model.law)    # a known law, before any work
    _check_integration(integ)
    skin = _skin(dec, r)
    slab_axis = _slab_axis(dec.slab_axis, x, r, dim, cell)

    gids = np.arange(n, dtype=np.int64) if p.gids is None else _gids(p.gids, n)
    reach = 2.0 * float(r.max()) + skin
    L0_max = float(np.linalg.norm(x[pairs[:, 1]] - x[pairs[:, 0]], axis=1).max()) if len(pairs) else 0.0
    ghost_range = GHOST_STRETCH * L0_max + skin
    if model is not None:
        ghost_range = max(ghost_range, reach)
    split = dec.initial_split
    if not (isinstance(split, str) and split == "balanced"):
        if len(split) != comm.size - 1:
            raise ValueError(f"Decomposition.initial_split has {len(split)} fractions: expected {comm.size - 1} "
                             f"(one per cut between {comm.size} ranks) or \"balanced\"")

    if comm.size > 1:
        stripe = slice(comm.rank, None, comm.size)
        slabs = Slabs.balanced(comm, slab_axis, x[stripe, slab_axis], gids[stripe],
                               fractions=None if isinstance(split, str) else split)
        owned = slabs.owner(x[:, slab_axis], gids) == comm.rank
    else:
        owned = np.ones(n, bool)
    touch = owned[pairs[:, 0]] | owned[pairs[:, 1]]
    partners = np.setdiff1d(pairs[touch].ravel(), np.nonzero(owned)[0])
    rows = np.concatenate([np.nonzero(owned)[0], partners])
    elements = Elements.from_spheres(x[rows], r[rows], density, gids[rows])
    elements.n_owned = int(owned.sum())
    if v0 is not None:
        elements.v[:] = v0[rows]
    if w0 is not None:
        elements.w[:] = w0[rows]
    if material is not None:
        # also with no bond on this rank: the empty set then carries the material's switches
        # (damped, breakable, densify_p0), which bonds migrating in later inherit and which a
        # checkpoint written by this rank stores
        local_row = np.full(n, -1, dtype=np.int64)
        local_row[rows] = np.arange(len(rows))
        bonds = make_bonds(elements, local_row[pairs[touch]], material, frame,
                           gids=np.arange(len(pairs), dtype=np.int64)[touch])
    else:
        bonds = Bonds.empty()
    contacts = None
    if model is not None:
        if model.resolve is not None:
            model = ContactModel(model.law, dict(model.resolve(comm, elements, bonds)))
            prm = model.law_params()
        contacts = Contacts(LAWS[model.law], prm, skin, cell, reach=reach)

    domain = None
    if comm.size > 1:
        domain = SlabComm(comm, slabs, ghost_range, skin, balance_every=dec.balance_every,
                          threshold=dec.balance_threshold, balance_by=dec.balance_by, cell=cell)
        if contacts is None:
            elements, bonds = domain.setup(elements, bonds)
        else:
            elements, bonds, table = domain.setup_with_pairs(elements, bonds, contacts.table())
            contacts.rebuild(elements, bonds, table)
    else:
        if cell is not None:
            cell.wrap(elements)
        bonds.relink(elements.gid)
        if contacts is not None:
            contacts.rebuild(elements, bonds)

    # a placeholder step, replaced once the critical step is known
    sim = Simulation(comm, elements, bonds, None, 1.0, max_speed=integ.max_speed, check_every=integ.check_every,
                     domain=domain, contacts=contacts, cell=cell, viscous_damping=integ.viscous_damping,
                     orientation=integ.orientation, max_step_displacement=integ.max_step_displacement)
    if dim == 2:
        sim.fixes.append(PlaneConstraint(0.0))
    if system.walls is not None:
        w = system.walls
        if not isinstance(w, WallModel):
            raise ValueError(f"System.walls must be a WallModel, got {type(w).__name__}")
        w.exact(add_walls(sim, w.normals, w.points, w.velocities, law=w.law, check_dt=False,
                          motions=_copies(w.motions), cylinders=_copies(w.cylinders),
                          meshes=_copies(w.meshes))).move_to(0.0)
    dt_c = critical_time_step_of(sim, contacts_of=(model, r, density))
    if integ.dt is None:
        if not math.isfinite(dt_c):
            raise ValueError("Integration.dt: nothing in this system is stiff (no bond, wall or contact): "
                             "give dt [s]")
        dt = float(integ.dt_fraction) * dt_c
    elif integ.dt > dt_c:
        raise ValueError(f"Integration.dt = {integ.dt:.6g} s is above the critical time step {dt_c:.6g} s "
                         f"of this system: expected a value in (0, {dt_c:.6g}] s, or None for "
                         f"dt_fraction = {integ.dt_fraction} of it")
    else:
        dt = float(integ.dt)
    sim.dt = dt
    sim.dt_critical = float(dt_c)
    if cell is not None:
        _check_cell_rates(cell, dt)
    if system.walls is not None:
        check_servos(sim, sim.plates)
    sim.density = density
    sim.system = replace(system, particles=None, contacts=model,
                         bonds=None if system.bonds is None else replace(system.bonds, pairs=None),
                         integration=replace(integ, dt=dt),
                         decomposition=replace(dec, skin=skin, slab_axis=int(slab_axis)),
                         cell=None if system.cell is None else replace(system.cell, state=None))
    sim.reach = reach
    sim.ghost_range = ghost_range
    sim.n_elements = n
    return sim


def _particle_arrays(p, dim):
    """Centres [n, 3], radii [n], density of ``p``, checked."""
    x = inputs.check_positions(p.positions, dim, "Particles.positions")
    r = inputs.check_radii(p.radii, len(x), "Particles.radii")
    density = inputs.check_density(p.density, len(x), "Particles.density")
    if not np.isscalar(density):
        raise ValueError("Particles.density must be one number [kg/m^3] for the system (one per particle is "
                         "not supported yet)")
    inputs.check_mass(r, density)
    return x, r, float(density)


def _cell(cell, radii, dim):
    """The ``PeriodicCell`` of the description (None without one)."""
    if cell is None:
        if dim == 2:
            raise ValueError("System.cell: the 2D mode needs a cell (its z edge is the thickness of "
                             "the stress convention)")
        return None
    if not isinstance(cell, Cell):
        raise ValueError(f"System.cell must be a pardem Cell, got {type(cell).__name__}")
    if cell.state is not None:
        return PeriodicCell.from_state(cell.state)
    if dim == 2:
        lo, length, per = plane_cell(cell.lo, cell.length, cell.periodic, radii, cell.thickness)
        rate = np.asarray(cell.rate, dtype=np.float64)
        if rate.shape != (3,) or rate[2] != 0.0:
            raise ValueError(f"Cell.rate must be 3 rates [1/s] with rate[2] = 0 in 2D, got {rate.tolist()}")
    else:
        lo, length, per, rate = cell.lo, cell.length, cell.periodic, cell.rate
    return PeriodicCell(lo, length, per, rate, cell.servo, dimension=dim, shear_rate=cell.shear_rate)


def plane_cell(box_lo, box_length, periodic, radii, thickness=None):
    """The 2D cell's ``(lo [3], length [3], periodic [3])``: x, y from ``box_lo``, ``box_length``,
    ``periodic`` (2 or 3 entries; z entries ignored), z not periodic, ``length[2]`` the thickness
    [m] (default the mean diameter ``2 <R>``) and ``lo[2] = -t / 2`` (the plane z = 0 in the middle)."""
    t = 2.0 * float(np.mean(radii)) if thickness is None else float(thickness)
    if not (np.isfinite(t) and t > 0.0):
        raise ValueError(f"Cell.thickness must be a finite length > 0 [m], got {thickness!r}")
    arrays = []
    for name, value, dtype in (("lo", box_lo, np.float64), ("length", box_length, np.float64),
                               ("periodic", periodic, bool)):
        try:
            arrays.append(np.asarray(value, dtype=dtype))
        except (TypeError, ValueError):
            raise ValueError(f"Cell.{name} must hold 2 or 3 {'booleans' if dtype is bool else 'numbers'} "
                             f"in 2D, got {value!r:.80}") from None
    lo, edge, per = arrays
    for name, a in (("lo", lo), ("length", edge), ("periodic", per)):
        if a.shape not in ((2,), (3,)):
            raise ValueError(f"Cell.{name} must hold 2 or 3 entries in 2D, got shape {a.shape}")
    return (np.array([lo[0], lo[1], -0.5 * t]), np.array([edge[0], edge[1], t]),
            np.array([per[0], per[1], False]))


def _bond_model(bonds, n):
    """(pairs [b, 2] sorted, material or None, frame [3, 3])."""
    if bonds is None:
        return np.zeros((0, 2), np.int64), None, np.eye(3)
    if not isinstance(bonds, BondModel):
        raise ValueError(f"System.bonds must be a BondModel, got {type(bonds).__name__}")
    if not isinstance(bonds.material, BeamMaterial):
        raise ValueError(f"BondModel.material must be a pardem BeamMaterial, got {type(bonds.material).__name__}")
    pairs = inputs.check_pairs(np.zeros((0, 2), np.int64) if bonds.pairs is None else bonds.pairs, n,
                               "BondModel.pairs")
    return pairs, bonds.material, inputs.check_frame(bonds.frame, "BondModel.frame")


def _check_integration(integ):
    if not isinstance(integ, Integration):
        raise ValueError(f"System.integration must be a pardem Integration, got {type(integ).__name__}")
    f = integ.dt_fraction
    if isinstance(f, bool) or not isinstance(f, (int, float, np.floating)) or not 0.0 < f <= 1.0:
        raise ValueError(f"Integration.dt_fraction must be a number in (0, 1], got {f!r}")
    if integ.dt is not None:
        _positive(integ.dt, "Integration.dt", "[s] (or None for dt_fraction of the critical step)")
    inputs.check_viscous_damping(integ.viscous_damping, "Integration.viscous_damping")
    _positive(integ.max_speed, "Integration.max_speed", "[m/s]")
    _positive(integ.max_step_displacement, "Integration.max_step_displacement",
              "(a fraction of the smallest radius per step)")
    k = integ.check_every
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"Integration.check_every must be an integer >= 1 [steps], got {k!r}")
    if not isinstance(integ.orientation, (bool, np.bool_)):
        raise ValueError(f"Integration.orientation must be True or False, got {integ.orientation!r}")


# the largest strain of the cell in one step: more is no deformation a step resolves (the grains
# jump by a tenth of the cell; absurd rates overflowed the neighbour grid). Loose on purpose: tests
# shear small cells at a few 1e-3 per step
MAX_CELL_STRAIN_PER_STEP = 0.1


def _check_cell_rates(cell, dt):
    """ValueError when the cell's strain rate or shear rate [1/s] strains it by more than
    ``MAX_CELL_STRAIN_PER_STEP`` in one step ``dt`` [s]."""
    for name, rates in (("Cell.rate", cell.rate), ("Cell.shear_rate", cell.shear_rate)):
        worst = float(np.max(np.abs(rates)))
        if not worst * dt <= MAX_CELL_STRAIN_PER_STEP:
            raise ValueError(f"{name} = {np.asarray(rates).tolist()} [1/s]: expected |rate| <= "
                             f"{MAX_CELL_STRAIN_PER_STEP / dt:.6g} 1/s (a strain of at most "
                             f"{MAX_CELL_STRAIN_PER_STEP:g} per step of dt = {dt:.6g} s)")


def _slab_axis(axis, x, r, dim, cell=None):
    """The slab axis of ``Decomposition.slab_axis``; with a shearing ``cell``, one its shear does
    not move (``PeriodicCell.slab_axis_allowed``)."""
    allowed = [True] * 3 if cell is None else [cell.slab_axis_allowed(a) for a in range(3)]
    if isinstance(axis, str) and axis == "auto":
        extent = np.ptp(x, axis=0) + 2.0 * float(r.mean())
        if dim == 2:
            extent[2] = 0.0
        extent = np.where(allowed, extent, -1.0)
        return choose_axis(extent)
    if axis in (0, 1, 2) and not isinstance(axis, bool) and not allowed[axis]:
        raise ValueError(f"Decomposition.slab_axis = {axis}: the cell's shear moves the "
                         f"{'xyz'[axis]} coordinates with another axis; expected an axis it does not "
                         f"move: {', '.join(str(a) for a in range(3) if allowed[a])} or 'auto'")
    allowed = (0, 1) if dim == 2 else (0, 1, 2)
    if isinstance(axis, bool) or axis not in allowed:
        raise ValueError(f"Decomposition.slab_axis = {axis!r}: expected "
                         f"{', '.join(map(str, allowed))} or 'auto'" + (" in 2D" if dim == 2 else ""))
    return int(axis)


# -- the description of a running simulation -------------------------------------------------

def describe(sim):
    """The model of ``sim`` now (a ``System`` without particles or bonded pairs): its current
    contact parameters, damping, time step, walls and cell state. Local (no collective)."""
    base = sim.system
    contacts = None
    if sim.contacts is not None:
        contacts = ContactModel(contact_law_name(sim.contacts), _init_fields(sim.contacts.params))
    walls = None
    if isinstance(sim.plates, Walls):
        w = sim.plates
        walls = WallModel(w.normals.copy(), w.normals * w.offsets0[:, None], w.law, w.velocities.copy(), w.time0,
                          w.offsets0.copy(), _described(w.motions), _described(w.cylinders),
                          _described(w.meshes))
    elif sim.plates is not None:
        raise ValueError("describe: this simulation's plates belong to a protocol (the compression test "
                         "saves them itself); a System holds planar walls (WallModel)")
    cell = None
    if sim.cell is not None:
        cell = replace(base.cell if base.cell is not None else Cell(), state=sim.cell.state())
    integ = replace(base.integration, dt=float(sim.dt), viscous_damping=float(sim.viscous_damping),
                    max_speed=float(math.sqrt(sim.max_speed2)), check_every=int(sim.check_every),
                    orientation=bool(sim.orientation), max_step_displacement=float(sim.step_displacement))
    d = sim.domain
    dec = base.decomposition
    if d is not None:
        dec = replace(dec, slab_axis=int(d.slabs.axis), balance_every=int(d.balance_every),
                      balance_threshold=float(d.threshold), balance_by=d.balance_by)
    return replace(base, particles=None, contacts=contacts, walls=walls, cell=cell, integration=integ,
                   decomposition=dec, dimension=2 if plane_of(sim) is not None else base.dimension)


def regrown(sim, positions, radii, velocities, angular_velocities, lo, length, periodic, gids=None):
    """The description of a new system like ``sim`` (its contacts, density, time step, damping,
    skin, decomposition, 2D mode) of other particles in another cell (a packing opened along some
    axes or replicated, ``pardem.engine.open_cell``, ``pardem.engine.replicate``): global arrays
    [n, 3] [m], [n] [m], [n, 3] [m/s], [n, 3] [rad/s], their ``gids`` [n] (increasing; default
    0 .. n-1); the cell ``lo``, ``length`` [3] [m], ``periodic`` [3]; it does not deform (rate 0,
    no servo) and there are no walls."""
    model = describe(sim)
    thickness = sim.cell.thickness if model.dimension == 2 else None
    return replace(model, particles=Particles(positions, radii, sim.density, velocities, angular_velocities,
                                              gids=gids),
                   cell=Cell(np.asarray(lo), np.asarray(length), tuple(bool(p) for p in periodic),
                             thickness=thickness), walls=None)


def set_contact_params(sim, params):
    """Switch every rank's contact parameters (dict, same law) between steps, e.g. friction after a
    frictionless preparation or the cement springs before ``pardem.engine.cement.cement_contacts``; the
    history is widened as the law needs; ``sim.system`` follows (so do checkpoints written after).
    ValueError when ``sim.dt`` is above the new parameters' critical step."""
    name = contact_law_name(sim.contacts)
    prm = law_params(name, params)
    e = sim.elements
    radii = e.radius[:e.n_owned]
    r_min = float(sim.comm.min(float(radii.min()) if len(radii) else np.inf))
    dt_c = critical_time_step(name, prm, np.array([r_min]), sim.density)
    if not sim.dt <= dt_c:
        raise ValueError(f"dt = {sim.dt:.6g} s is above the critical step {dt_c:.6g} s of the new "
                         "contact parameters")
    sim.contacts.set_params(prm)
    sim.system = replace(sim.system, contacts=ContactModel(name, dict(params)))
    sim.dt_critical = dt_c


def restore(comm, system, parts, cell, density):
    """The ``Simulation`` of a checkpoint's ``parts`` (``pardem.restart.read``: elements, bonds,
    contacts, slab layer) with the model ``system`` (``System.from_dict`` of what ``describe`` gave
    when it was written), the cell ``cell`` and the grains' ``density`` [kg/m^3]. The caller
    resumes the clock (``pardem.engine.snapshot.resume``)."""
    integ = system.integration
    walls = None
    if system.walls is not None:
        w = system.walls
        walls = w.make()
    sim = Simulation(comm, parts.elements, parts.bonds, walls, integ.dt, max_speed=integ.max_speed,
                     check_every=integ.check_every, domain=parts.domain, contacts=parts.contacts, cell=cell,
                     viscous_damping=integ.viscous_damping, orientation=integ.orientation,
                     max_step_displacement=integ.max_step_displacement)
    if int(system.dimension) == 2:
        sim.fixes.append(PlaneConstraint(0.0))
    if walls is not None:
        attach_servos(sim, walls)
    sim.density = float(density)
    sim.system = replace(system, particles=None)
    return sim


def parts_cell(system):
    """The ``PeriodicCell`` of a stored model (None without a cell)."""
    if system.cell is None:
        return None
    if system.cell.state is None:
        raise ValueError("a stored cell holds its state (System written by describe)")
    return PeriodicCell.from_state(system.cell.state)


__all__ = ["System", "Particles", "ContactModel", "BondModel", "WallModel", "Cell", "Integration",
           "Decomposition", "build", "describe", "regrown", "set_contact_params", "critical_time_step_of",
           "plane_cell"]
