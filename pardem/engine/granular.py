"""Granular cases: spheres interacting by contact in a periodic cell, on any number of ranks.

Composes the pieces (no physics here): ``Elements`` from given centres and radii, the
``PeriodicCell``, ``Contacts`` with one law, the slab layer when there are several ranks (periodic
slab axis allowed), and a ``Simulation``; plus the checkpoint payload and the restart of such a
case. Used by the GRAN benchmark, the granular tests and the granular drivers.

Between steps a driver may switch the contact parameters (``set_contact_params``: e.g. friction
after a frictionless preparation, or cemented Hertz-Mindlin contacts, whose history is wider) and
the global damping (``set_viscous_damping``); both update the restart constants, so a checkpoint
written afterwards restarts with them. Cementation itself is ``pardem.engine.cement``.

2D mode (``dimension=2``, ``pardem.engine.plane``): centres in the plane z = 0, a cell periodic
along x and y only whose z edge is the thickness of the stress convention (``thickness``, default
the mean diameter), and the ``PlaneConstraint`` fix; the constants record ``dimension`` and
``thickness`` and ``restore`` puts the fix back.

The contact history lives in the checkpoint as each rank's list (see ``pardem.io.checkpoint``), so
a restart on the same number of ranks continues bit for bit; on another number of ranks the lists
are rebuilt and the histories found again by their gid pairs.
"""
from dataclasses import dataclass, field

import numpy as np

from pardem.engine import snapshot
from pardem.engine.contacts import Contacts
from pardem.engine.plane import PlaneConstraint, check_dimension, in_plane, planar
from pardem.io import checkpoint
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import Slabs
from pardem.engine.periodic_cell import PeriodicCell
from pardem.physics.contact_laws import LAWS, critical_time_step, law_params
from pardem.engine.simulation import Simulation
from pardem.engine.state import Bonds, Elements


def simple_cubic(n, radius, spacing=1.998, jitter=0.0002, seed=12345):
    """Centres [n^3, 3] of a simple cubic lattice of spacing ``spacing * radius`` jittered by
    ``+-jitter * radius`` per axis (uniform, seeded), and the periodic box edge [m]."""
    rng = np.random.default_rng(seed)
    a = spacing * radius
    g = np.arange(n) * a + 0.5 * a
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    pos += rng.uniform(-jitter * radius, jitter * radius, size=pos.shape)
    return pos, n * a


@dataclass
class GranularCase:
    """A granular simulation on this rank and the constants needed to restart it."""
    sim: Simulation
    constants: dict = field(default_factory=dict)


def set_contact_params(case, params):
    """Switch every rank's contact parameters (dict, same law) between steps, e.g. friction after a
    frictionless preparation or the cement springs before ``pardem.engine.cement.cement_contacts``; the
    history is widened as the law needs, and the restart constants follow."""
    c = case.constants
    prm = law_params(c["law"], params)
    sim = case.sim
    radii = sim.elements.radius[:sim.elements.n_owned]
    r_min = float(sim.comm.min(float(radii.min()) if len(radii) else np.inf))
    dt_c = critical_time_step(c["law"], prm, np.array([r_min]), c["density"])
    if not sim.dt <= dt_c:
        raise ValueError(f"dt = {sim.dt:.6g} s is above the critical step {dt_c:.6g} s of the new "
                         "contact parameters")
    sim.contacts.set_params(prm)
    c["params"] = dict(params)
    c["dt_critical"] = dt_c


def set_viscous_damping(case, rate):
    """Change the global viscous damping C [1/s] between steps (the restart constants follow)."""
    case.sim.viscous_damping = float(rate)
    case.constants["viscous_damping"] = float(rate)


def plane_cell(box_lo, box_length, periodic, radii, thickness=None):
    """The 2D cell's ``(lo [3], length [3], periodic [3])``: x, y from ``box_lo``, ``box_length``,
    ``periodic`` (2 or 3 entries; z entries ignored), z not periodic, ``length[2]`` the thickness
    [m] (default the mean diameter ``2 <R>``) and ``lo[2] = -t / 2`` (the plane z = 0 in the middle)."""
    t = 2.0 * float(np.mean(radii)) if thickness is None else float(thickness)
    if not (np.isfinite(t) and t > 0.0):
        raise ValueError(f"thickness must be a finite length > 0 [m], got {thickness!r}")
    lo = np.asarray(box_lo, dtype=np.float64)
    edge = np.asarray(box_length, dtype=np.float64)
    per = np.asarray(periodic, dtype=bool)
    for name, a in (("box_lo", lo), ("box_length", edge), ("periodic", per)):
        if a.shape not in ((2,), (3,)):
            raise ValueError(f"{name} must hold 2 or 3 entries in 2D, got shape {a.shape}")
    return (np.array([lo[0], lo[1], -0.5 * t]), np.array([edge[0], edge[1], t]),
            np.array([per[0], per[1], False]))


def build(comm, positions, radii, density, law, params, box_lo, box_length, dt, skin,
          periodic=(True, True, True), rate=(0.0, 0.0, 0.0), servo=None, viscous_damping=0.0,
          velocities=None, angular_velocities=None, slab_axis=0, balance_every=0, dimension=3,
          thickness=None, orientation=True):
    """A granular case from global centres [n, 3] and radii [n] (every rank passes the same).

    density [kg/m^3]; law, params: the contact law and its parameters (dict); box_lo [3],
    box_length [3] [m]: the periodic cell; dt [s]; skin [m]; rate [3] [1/s], servo
    ``(p0, gain, max_rate)``: the cell's deformation; velocities [n, 3] [m/s] optional.
    Rank r keeps its slab's elements (slabs along ``slab_axis``, balanced counts).

    ``dimension=2``: the 2D mode (``pardem.engine.plane``): centres [n, 2] or [n, 3] with z = 0;
    the cell is x, y of ``box_lo``, ``box_length``, ``periodic`` with the thickness ``thickness``
    [m] (default the mean diameter) along z (``plane_cell``); ``rate[2]`` must be 0; the
    out-of-plane components of ``velocities`` (z) and ``angular_velocities`` (x, y) are dropped;
    ``slab_axis`` 0 or 1.

    ``orientation`` False: the grains' orientations are not integrated (``Simulation``; no contact
    law reads them, LAMMPS' ``fix nve/sphere`` does not either); recorded for the restart.
    """
    dimension = check_dimension(dimension)
    if dimension == 2:
        pos = planar(positions)
        n = len(pos)
        radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (n,))
        box_lo, box_length, periodic = plane_cell(box_lo, box_length, periodic, radii, thickness)
        rate = np.asarray(rate, dtype=np.float64)
        if rate.shape != (3,) or rate[2] != 0.0:
            raise ValueError(f"rate must be 3 rates [1/s] with rate[2] = 0 in 2D, got {rate.tolist()}")
        if slab_axis not in (0, 1):
            raise ValueError(f"slab_axis = {slab_axis!r}: expected 0 (x) or 1 (y) in 2D (the grains lie "
                             "in the plane z = 0)")
        velocities = in_plane(velocities, (2,), "velocities")
        angular_velocities = in_plane(angular_velocities, (0, 1), "angular_velocities")
    pos = np.asarray(positions if dimension == 3 else pos, dtype=np.float64)
    per = np.asarray(periodic, dtype=bool)
    lo0, edge = np.asarray(box_lo, dtype=np.float64), np.asarray(box_length, dtype=np.float64)
    pos = np.where(per, lo0 + np.mod(pos - lo0, edge), pos)   # slabs are cut in the cell's frame
    n = len(pos)
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (n,))
    prm = law_params(law, params)
    dt_c = critical_time_step(law, prm, radii, density)
    if not 0.0 < dt <= dt_c:
        raise ValueError(f"dt = {dt:.6g} s: expected a value in (0, {dt_c:.6g}] s, the critical time "
                         f"step of the {law} contacts of these spheres (take 0.1-0.3 of it)")
    gids = np.arange(n, dtype=np.int64)
    cell = PeriodicCell(box_lo, box_length, periodic, rate, servo, dimension=dimension)
    reach = 2.0 * float(radii.max()) + float(skin)
    constants = {"density": float(density), "law": law, "params": dict(params), "dt": float(dt),
                 "skin": float(skin), "reach": reach, "slab_axis": int(slab_axis),
                 "viscous_damping": float(viscous_damping), "n_elements": n,
                 "balance_every": int(balance_every), "dt_critical": dt_c,
                 "orientation": bool(orientation)}
    if dimension == 2:
        constants.update(dimension=2, thickness=cell.thickness)
    contacts = Contacts(LAWS[law], prm, skin, cell, reach=reach)
    domain = None
    if comm.size > 1:
        stripe = slice(comm.rank, None, comm.size)
        slabs = Slabs.balanced(comm, slab_axis, pos[stripe, slab_axis], gids[stripe])
        owned = slabs.owner(pos[:, slab_axis], gids) == comm.rank
    else:
        owned = np.ones(n, dtype=bool)
    e = Elements.from_spheres(pos[owned], radii[owned], density, gids[owned])
    if velocities is not None:
        e.v[:] = np.asarray(velocities)[owned]
    if angular_velocities is not None:
        e.w[:] = np.asarray(angular_velocities)[owned]
    bonds = Bonds.empty()
    if comm.size > 1:
        domain = SlabComm(comm, slabs, reach, skin, balance_every=balance_every, cell=cell)
        e, bonds, table = domain.setup_with_pairs(e, bonds, contacts.table())
        contacts.rebuild(e, bonds, table)
    else:
        cell.wrap(e)
        contacts.rebuild(e, bonds)
    sim = Simulation(comm, e, bonds, None, dt, domain=domain, contacts=contacts, cell=cell,
                     viscous_damping=viscous_damping, orientation=orientation)
    if dimension == 2:
        sim.fixes.append(PlaneConstraint(0.0))
    return GranularCase(sim=sim, constants=constants)


def checkpoint_payload(case, attrs=None):
    """(groups, series, attrs) for ``checkpoint.write_checkpoint`` (every rank): the case's state
    (``pardem.engine.snapshot.payload``), its constants and the caller's ``attrs``."""
    from pardem.engine.walls import Walls
    p = case.sim.plates
    if p is not None and not isinstance(p, Walls):
        raise ValueError("granular.write saves the walls of add_walls only (a compression test's plates are "
                         "saved by its protocol)")
    constants = case.constants if p is None else {**case.constants, "walls": snapshot.wall_attrs(p)}
    groups, attrs = snapshot.payload(case.sim, {"deck": {"kind": "granular"}, "constants": constants,
                                                "slab_axis": case.constants["slab_axis"], **(attrs or {})})
    return groups, {}, attrs


def write(case, path, mode="auto"):
    groups, series, attrs = checkpoint_payload(case)
    checkpoint.write_checkpoint(path, case.sim.comm, groups, series, attrs, mode=mode)


def restore(comm, path, slab_axis=None, meta=None):
    """The granular case of checkpoint ``path`` on ``comm`` (any number of ranks; ``slab_axis``
    re-cuts the slabs along another axis). On the rank count and axis that wrote it the run
    continues bit for bit. ``meta``: the file's attributes when already inspected."""
    meta = checkpoint.inspect(path, comm=comm) if meta is None else meta
    c = meta["constants"]
    cell = snapshot.cell_of(meta)
    if slab_axis is not None:
        if int(c.get("dimension", 3)) == 2 and int(slab_axis) not in (0, 1):
            raise ValueError(f"slab_axis = {slab_axis!r}: expected 0 (x) or 1 (y) for a 2D checkpoint "
                             "(the grains lie in the plane z = 0)")
        c["slab_axis"] = int(slab_axis)
    contacts = Contacts(LAWS[c["law"]], law_params(c["law"], c["params"]), c["skin"], cell,
                        reach=c["reach"])
    parts = snapshot.read(comm, path, meta, int(c["slab_axis"]), contacts=contacts,
                          slab_comm=lambda slabs: SlabComm(comm, slabs, c["reach"], c["skin"],
                                                           balance_every=c["balance_every"], cell=cell))
    walls = snapshot.walls_of(c.pop("walls", None))
    sim = Simulation(comm, parts.elements, parts.bonds, walls, c["dt"], domain=parts.domain,
                     contacts=contacts, cell=cell, viscous_damping=c["viscous_damping"],
                     orientation=bool(c.get("orientation", True)))   # older files: integrated
    if int(c.get("dimension", 3)) == 2:
        sim.fixes.append(PlaneConstraint(0.0))
    snapshot.resume(sim, meta, parts.same)
    if walls is not None:
        walls.move_to(sim.time)
    return GranularCase(sim=sim, constants=c)


def continue_clock(sim, step, time):
    """Let a freshly built ``sim`` (step 0) continue the step count ``step`` and time ``time`` [s]
    of the run it belongs to (series, checkpoints and snapshots count steps from the run's start:
    a case rebuilt after opening or replicating a packing): the forces of its first state are
    computed first, as ``Simulation.run`` does at step 0."""
    if int(step) == 0:
        return                  # the first run computes them (``Simulation.run`` at step 0)
    if sim.step_count == 0:
        sim.run(0)
    sim.step_count, sim.time = int(step), float(time)
    sim.set_dt(sim.dt)          # the clock counts from here
