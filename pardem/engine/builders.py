"""Ready-to-run ``Simulation`` objects for scripts: bonded systems and granular systems.

``bonded_system`` takes global arrays (every rank passes the same ones): centres, radii, the bonded
pairs and a ``BeamMaterial``. On one rank it builds the elements and bonds directly; on several it
cuts slabs (``pardem.parallel.slabs``), keeps on each rank its slab's elements plus the partners of
their bonds, and lets the slab layer (``pardem.parallel.slab_comm.SlabComm``) migrate and build the
ghosts, exactly as the compression test does (``pardem.protocols.compression.build_case``). The time
step is checked against the critical step of velocity Verlet (``critical_time_step``: the block
Gershgorin bound of ``pardem.physics.timestep`` over bonds and walls, and the contact law's step).

Element ``k`` of the arrays has global id ``k`` (``elements.gid``): fixes select elements by it.
"""
import numpy as np

from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.engine.contacts import Contacts
from pardem.engine.granular import LAWS as CONTACT_LAWS
from pardem.engine.granular import build as granular_build
from pardem.engine.granular import critical_time_step as contact_critical_time_step
from pardem.engine.granular import law_params
from pardem.engine.simulation import Simulation
from pardem.engine.state import Bonds, Elements
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import Slabs, choose_axis
from pardem.physics.timestep import critical_time_step as verlet_critical_step
from pardem.physics.timestep import eigen_bound, max_tau

GHOST_STRETCH = 1.25   # bonds may stretch by 25 % before they outgrow the ghost layer (as compression)
SKIN_RADII = 0.2       # default skin: 0.2 mean radius (as compression)


def _contact_law_name(contacts):
    for name, module in CONTACT_LAWS.items():
        if contacts.law is module:
            return name
    raise ValueError(f"unknown contact law module {contacts.law!r}")


def critical_time_step(sim, walls=None):
    """Critical time step [s] of ``sim`` (collective: every rank calls it, all get the same value).

    Bonds and walls: ``sqrt(tau^2 + 4 / omega_max^2) - tau`` with ``omega_max^2`` the block
    Gershgorin bound of ``pardem.physics.timestep.eigen_bound`` (each element also feels the wall
    stiffness ``walls.stiffness(R) / m``, as if it touched a wall) and ``tau`` the largest bond
    damping time. Contacts: the law's step (``pardem.engine.granular.critical_time_step``).
    ``walls``: a ``pardem.engine.walls.Walls`` (default ``sim.plates`` when it is one). ``inf``
    when nothing is stiff.
    """
    comm, e, b = sim.comm, sim.elements, sim.bonds
    if b is None:
        b = Bonds.empty()
    if walls is None and hasattr(sim.plates, "stiffness") and callable(sim.plates.stiffness):
        walls = sim.plates
    n = e.n_owned
    r_max = float(comm.max(float(e.radius[:n].max()) if n else 0.0))
    k_wall = walls.stiffness(r_max) if walls is not None else 0.0
    lam = eigen_bound(b.i, b.j, b.L0, b.ka, b.kb, b.kt, e.mass, e.inertia, n,
                      np.ascontiguousarray(k_wall / e.mass))
    dt_c = verlet_critical_step(comm.max(float(lam)), comm.max(max_tau(b)))
    if sim.contacts is not None:
        # the smallest sphere and the smallest mass (the same element for a uniform density)
        r_min = float(comm.min(float(e.radius[:n].min()) if n else np.inf))
        m_min = float(comm.min(float(e.mass[:n].min()) if n else np.inf))
        rho = m_min / (4.0 / 3.0 * np.pi * r_min**3)
        dt_c = min(dt_c, contact_critical_time_step(_contact_law_name(sim.contacts), sim.contacts.params,
                                                    np.array([r_min]), rho))
    return float(dt_c)


def _check_arrays(positions, radii, density, pairs):
    x = np.ascontiguousarray(positions, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 1 or not np.all(np.isfinite(x)):
        raise ValueError(f"positions must be finite with shape (n, 3), n >= 1 [m], got shape {np.shape(positions)}")
    n = len(x)
    r = np.asarray(radii, dtype=np.float64)
    if r.shape not in ((), (n,)):
        raise ValueError(f"radii must be a scalar or have shape ({n},) [m], got shape {r.shape}")
    r = np.ascontiguousarray(np.broadcast_to(r, (n,)))
    if not np.all(np.isfinite(r) & (r > 0.0)):
        raise ValueError(f"radii must be finite and > 0 [m], got min {r.min()}")
    if not (np.isscalar(density) and np.isfinite(density) and density > 0.0):
        raise ValueError(f"density must be a finite number > 0 [kg/m^3], got {density!r}")
    p = np.asarray(pairs)
    if p.size == 0:
        p = np.zeros((0, 2), np.int64)
    if p.ndim != 2 or p.shape[1] != 2 or p.dtype.kind not in "iu":
        raise ValueError(f"pairs must be integer indices of shape (b, 2) into positions, got "
                         f"{p.dtype} shape {p.shape}")
    p = p.astype(np.int64)
    if len(p) and (p.min() < 0 or p.max() >= n):
        raise ValueError(f"pairs must index elements 0 .. {n - 1}, got values in [{p.min()}, {p.max()}]")
    if np.any(p[:, 0] == p[:, 1]):
        raise ValueError("pairs must join two different elements (a row has twice the same index)")
    p = np.sort(p, axis=1)
    p = p[np.lexsort((p[:, 1], p[:, 0]))]
    if len(p) > 1 and np.any(np.all(p[1:] == p[:-1], axis=1)):
        raise ValueError("pairs must not list the same bond twice")
    return x, r, p


def _check_frame(frame):
    if frame is None:
        return np.eye(3)
    f = np.asarray(frame, dtype=np.float64)
    if f.shape != (3, 3) or not np.allclose(f @ f.T, np.eye(3), atol=1e-9):
        raise ValueError(f"frame must be a (3, 3) orthonormal matrix whose rows are the material axes L, R, T "
                         f"in world coordinates, got {f.tolist()}")
    return f


def bonded_system(comm, positions, radii, density, pairs, material, frame=None, dt=None,
                  dt_fraction=0.3, walls=None, contacts=None, viscous_damping=0.0, velocities=None,
                  skin=None, slab_axis="auto", balance_every=0, max_speed=1e4):
    """A ``Simulation`` of spheres joined by Euler-Bernoulli beam bonds (every rank, same arguments).

    positions [n, 3] [m] : centres (element k gets global id k); radii [n] or scalar [m];
    density [kg/m^3]; pairs [b, 2] : indices into ``positions`` of the bonded elements (any order,
    each bond once); material : ``pardem.engine.bonding.BeamMaterial`` (modulus, bond radius ratio
    r / mean(R1, R2), Poisson ratio, damping ratio, strengths).

    frame [3, 3] : the LRT material frame, rows = the longitudinal (L), radial (R) and tangential (T)
        material axes as unit vectors in world coordinates (``pardem.physics.anisotropy.lrt_frame``).
        An anisotropic ``material`` (``young`` or ``radius_ratio`` given as (L, R, T) triples) gives
        each bond the value its direction takes in this frame by ``material.law``; scalar (isotropic)
        properties ignore it. Default: identity (L = x, R = y, T = z).
    dt [s] : time step; default ``dt_fraction`` (0 < f <= 1) times the critical step. ValueError
        when dt is above the critical step (``critical_time_step``, walls and contacts included).
    walls : optional dict of ``pardem.engine.walls.add_walls`` keywords (``normals``, ``points``,
        ``velocities``, ``law``, ``stiffness``, ``restitution``, ``friction``, ...), added before the
        time step is chosen, so that dt accounts for them.
    contacts : optional dict ``{"law": "hertz_mindlin" | "linear", "params": {...}}`` of
        element-element contacts between unbonded pairs (``pardem.engine.granular.law_params``).
    viscous_damping [1/s] : global drag rate C (``-C m v``); velocities [n, 3] [m/s] : initial.
    skin [m] : neighbour/ghost skin (default 0.2 mean radius); slab_axis : 0, 1, 2 or "auto" (the
    longest extent); balance_every : steps between load-balance checks (0: never); max_speed [m/s].
    """
    x, r, pairs = _check_arrays(positions, radii, density, pairs)
    if not isinstance(material, BeamMaterial):
        raise ValueError(f"material must be a pardem.engine.bonding.BeamMaterial, got {type(material).__name__}")
    frame = _check_frame(frame)
    if not (0.0 < float(dt_fraction) <= 1.0):
        raise ValueError(f"dt_fraction must be in (0, 1], got {dt_fraction}")
    if dt is not None and not (np.isfinite(dt) and dt > 0.0):
        raise ValueError(f"dt must be a finite time step > 0 [s] (or None for dt_fraction of the critical step), got {dt}")
    n = len(x)
    v0 = None
    if velocities is not None:
        v0 = np.asarray(velocities, dtype=np.float64)
        if v0.shape != (n, 3) or not np.all(np.isfinite(v0)):
            raise ValueError(f"velocities must be finite with shape ({n}, 3) [m/s], got shape {v0.shape}")
    R_mean = float(r.mean())
    skin = SKIN_RADII * R_mean if skin is None else float(skin)
    if not skin > 0.0:
        raise ValueError(f"skin must be > 0 [m], got {skin}")
    gids = np.arange(n, dtype=np.int64)
    bond_gids = np.arange(len(pairs), dtype=np.int64)
    extent = np.ptp(x, axis=0) + 2.0 * R_mean
    if slab_axis == "auto":
        slab_axis = choose_axis(extent)
    elif slab_axis not in (0, 1, 2):
        raise ValueError(f"slab_axis must be 0, 1, 2 or 'auto', got {slab_axis!r}")

    contact_law = None
    if contacts is not None:
        if not isinstance(contacts, dict) or set(contacts) - {"law", "params"} or "law" not in contacts:
            raise ValueError("contacts must be a dict {'law': 'hertz_mindlin' | 'linear', 'params': {...}}, "
                             f"got {contacts!r}")
        contact_law = contacts["law"]
        prm = law_params(contact_law, contacts.get("params", {}))
    reach = 2.0 * float(r.max()) + skin
    L0_max = float(np.linalg.norm(x[pairs[:, 1]] - x[pairs[:, 0]], axis=1).max()) if len(pairs) else 0.0
    ghost_range = GHOST_STRETCH * L0_max + skin
    if contact_law is not None:
        ghost_range = max(ghost_range, reach)

    if comm.size > 1:
        stripe = slice(comm.rank, None, comm.size)
        slabs = Slabs.balanced(comm, slab_axis, x[stripe, slab_axis], gids[stripe])
        owned = slabs.owner(x[:, slab_axis], gids) == comm.rank
    else:
        owned = np.ones(n, bool)
    touch = owned[pairs[:, 0]] | owned[pairs[:, 1]]
    partners = np.setdiff1d(pairs[touch].ravel(), np.nonzero(owned)[0])
    rows = np.concatenate([np.nonzero(owned)[0], partners])
    local_row = np.full(n, -1, dtype=np.int64)
    local_row[rows] = np.arange(len(rows))
    elements = Elements.from_spheres(x[rows], r[rows], float(density), gids[rows])
    elements.n_owned = int(owned.sum())
    if v0 is not None:
        elements.v[:] = v0[rows]
    # also with no bond here: the empty set then carries the material's switches (damped,
    # breakable, densify_p0), which bonds migrating in later inherit (SlabComm.exchange unpacks
    # them with these flags) and which a checkpoint written by this rank stores
    bonds = make_bonds(elements, local_row[pairs[touch]], material, frame, gids=bond_gids[touch])
    cts = Contacts(CONTACT_LAWS[contact_law], prm, skin, None, reach=reach) if contact_law else None

    domain = None
    if comm.size > 1:
        domain = SlabComm(comm, slabs, ghost_range, skin, balance_every=balance_every)
        if cts is None:
            elements, bonds = domain.setup(elements, bonds)
        else:
            elements, bonds, table = domain.setup_with_pairs(elements, bonds, cts.table())
            cts.rebuild(elements, bonds, table)
    else:
        bonds.relink(elements.gid)
        if cts is not None:
            cts.rebuild(elements, bonds)

    # a placeholder step, replaced once the critical step is known
    sim = Simulation(comm, elements, bonds, None, 1.0, max_speed=max_speed, domain=domain,
                     contacts=cts, viscous_damping=viscous_damping)
    wall_set = None
    if walls is not None:
        from pardem.engine.walls import add_walls
        wall_set = add_walls(sim, check_dt=False, **walls)
    dt_c = critical_time_step(sim, wall_set)
    if viscous_damping > 0.0:
        dt_c = min(dt_c, 2.0 / viscous_damping)   # C dt < 2 (pardem.physics.viscous_damping)
    if dt is None:
        if not np.isfinite(dt_c):
            raise ValueError("nothing in this system is stiff (no bond, wall or contact): give dt")
        dt = float(dt_fraction) * dt_c
    elif dt > dt_c:
        raise ValueError(f"dt = {dt:.6g} s is above the critical time step {dt_c:.6g} s of this system: "
                         f"expected a value in (0, {dt_c:.6g}] s, or dt=None for {dt_fraction} of it")
    sim.dt = float(dt)
    sim.dt_critical = float(dt_c)
    if wall_set is not None:
        wall_set.time0 = 0.0
    return sim


def granular_system(comm, positions, radii, density, law, params, box_lo, box_length, dt=None,
                    dt_fraction=0.2, skin=None, **keywords):
    """A granular ``Simulation`` (contacts only, in a periodic cell) from global arrays.

    Wraps ``pardem.engine.granular.build`` (same arguments: law ``"hertz_mindlin"`` or ``"linear"``,
    params dict, cell ``box_lo`` [3] and ``box_length`` [3] [m], ``periodic``, ``rate``, ``servo``,
    ``viscous_damping``, ``velocities``, ``dimension`` (2: the 2D mode of ``pardem.engine.plane``,
    centres in the plane z = 0, cell periodic in x, y, ``thickness`` of the stress convention), ...)
    with dt defaulting to ``dt_fraction`` of the contact
    law's critical step and skin to 0.2 mean radius. The ``GranularCase`` constants (for
    ``pardem.engine.granular.write`` checkpoints) are kept as ``sim.case``.
    """
    x = np.asarray(positions, dtype=np.float64)
    r = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(x),))
    if dt is None:
        if not (0.0 < float(dt_fraction) <= 1.0):
            raise ValueError(f"dt_fraction must be in (0, 1], got {dt_fraction}")
        dt = float(dt_fraction) * contact_critical_time_step(law, law_params(law, params), r, density)
    skin = SKIN_RADII * float(r.mean()) if skin is None else skin
    case = granular_build(comm, x, r, density, law, params, box_lo, box_length, dt, skin, **keywords)
    case.sim.case = case
    return case.sim


__all__ = ["bonded_system", "granular_system", "critical_time_step"]
