"""The compression test between plates: build the case from a deck (or a checkpoint), run it,
measure the moduli. Used by the compress driver and by the tests; files are written by the driver
and the I/O layer.
"""
import copy
import math
import time
from dataclasses import dataclass, field, fields, replace

import numpy as np

from pardem.engine.bonding import BeamMaterial
from pardem.config import DeckError, check_deck, raw_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA, physics_differences, upgrade
from pardem import restart
from pardem.engine import snapshot
from pardem.io import checkpoint
from pardem.domains import compact
from pardem.engine.contacts import Contacts
from pardem.domains.ordered import ordered_lattice
from pardem.physics.contact_laws import LAWS as CONTACT_LAWS
from pardem.physics.contact_laws import critical_time_step as contact_critical_time_step
from pardem.physics.contact_laws import law_params
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import choose_axis
from pardem.physics import beam_static, walls
from pardem.physics.anisotropy import lrt_frame
from pardem.physics.timestep import critical_time_step, eigen_bound, max_tau
from pardem.engine.reducer import STRAIN_SUMS, Reducer, gradient_from_sums, strain_sums, young_and_poisson
from pardem.engine.simulation import Simulation
from pardem.engine.system import BondModel, ContactModel, Decomposition, Particles, System, build
from pardem.engine.state import FLAG_NEAR_PLATE, Bonds, Elements, Plates
from pardem.triggers import as_trigger

NEAR_PLATE_GAP = 0.5   # elements closer than this many radii to a plate at the start: not in the strain fit


@dataclass
class CompressionConstants:
    """Every derived quantity a compression run depends on, computed once from the deck and stored
    in checkpoints (``as_dict``), so that a restart reuses them exactly."""
    dt: float                 # time step [s]
    dt_critical: float        # critical step of bonds, plates and contacts [s]
    plate_stiffness: float    # linear element-plate stiffness, or the Hertz bound's [N/m]
    ramp_time: float          # smooth start of the moving plate [s]
    wall_young: float         # Hertz walls: the elements' Young's modulus [Pa]
    lateral_walls: list       # [[axis, position [m], normal sign], ...] of the fixed lateral walls
    plate_low: float          # initial plate positions along the loading axis [m]
    plate_high: float
    axis: int                 # loading axis (0, 1, 2)
    length: float             # initial plate gap [m]
    cross_section: float      # initial section across the load [m^2]
    transit_time: float       # axial wave crossing time [s]
    analytic_young: float     # pi/4 E r^2 of an ordered lattice loaded along a lattice axis, or nan [Pa]
    n_elements: int
    n_bonds: int
    origin: np.ndarray        # [3] origin of the strain fit [m]
    slab_axis: int
    ghost_range: float        # [m]
    skin: float               # [m]
    damped: bool              # bonds carry damping
    breakable: bool = False   # bonds can break
    densify_p0: float = 0.0   # densification p0 (0: elastic bonds)
    contact_law: str = "none"
    contact_params: dict = field(default_factory=dict)
    contact_reach: float = 0.0   # [m]
    domain_facts: dict = field(default_factory=dict)   # compact domains: solid fraction, coordination...

    def as_dict(self):
        """Flat JSON-able dict (the domain facts at the top level, as checkpoints store them)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "domain_facts"}
        return {**d, **self.domain_facts}

    @classmethod
    def from_dict(cls, d):
        """From ``as_dict`` (a checkpoint's ``constants``); unknown keys are domain facts."""
        names = {f.name for f in fields(cls)} - {"domain_facts"}
        c = cls(**{k: v for k, v in d.items() if k in names},
                domain_facts={k: v for k, v in d.items() if k not in names})
        c.origin = np.asarray(c.origin, dtype=np.float64)
        return c


@dataclass
class CompressionCase:
    """A compression test on this rank: the simulation, its reducer and the run constants.

    ``n_steps`` is the run's total step count from its start; ``samples`` the reducer's samples;
    ``compile_seconds`` the wall time of ``compile_step_kernels`` when the case was assembled (the
    kernels' compilation or cache loading, kept out of the run's timing).
    """
    sim: Simulation
    reducer: Reducer
    deck: dict
    constants: CompressionConstants
    n_steps: int
    samples: list = field(default_factory=list)
    compile_seconds: float = 0.0

    @property
    def steps_left(self):
        return max(0, self.n_steps - self.sim.step_count)


WALL_OVERLAP_BOUND = 0.05   # Hertz walls: the critical step holds up to this overlap / R
GHOST_STRETCH = 1.25   # bonds may stretch by 25 % before they would outgrow the ghost layer


def build_case(comm, deck, steps=None, packing=None, plates=True):
    """Elements, bonds, plates and time step of the deck's compression test on this rank.

    Every rank computes the lattice geometry (cheap), keeps its slab's elements and the bonds that
    touch them, then the slab layer builds the ghosts. A compact packing is built on rank 0 and
    broadcast, unless ``packing`` (a ``CompactPacking`` of this deck's domain, e.g. shared by the
    cases of one realisation) is given. Without ``plates`` the domain is built alone (other tests
    of the domain: the time step is the same, still bounded for plate contact).
    DeckError on a bad time step, split or domain.
    """
    dom, bd, ld, run, par = deck["domain"], deck["bonds"], deck["loading"], deck["run"], deck["parallel"]
    axis = "xyz".index(ld["axis"])
    if dom["kind"] == "compact":
        pos, radii, pairs, frame, facts = _compact_domain(comm, dom, axis, packing)
        R = facts["mean_radius"]
        lower = np.min(pos - radii[:, None], axis=0)
        upper = np.max(pos + radii[:, None], axis=0)
        # the box is the domain the elements represent (across the load, a periodic cell: each
        # sphere counted once); spheres sticking out of its cut faces would inflate it by ~2R/L
        extent = np.array(dom["box"], dtype=np.float64)
    else:
        R = dom["radius"]
        # a loading axis off the grid axes: flat faces under the plates (domains.ordered)
        off_grid = _lattice_axis(lrt_frame(dom["tilt_deg"]), axis) is None
        try:
            pos, pairs, frame = ordered_lattice(dom["box"], R, dom["tilt_deg"],
                                                flat_axis=axis if off_grid else None)
        except ValueError as err:
            raise DeckError(f"domain.box = {list(dom['box'])} with domain.radius = {R}: {err}") from None
        radii = np.full(len(pos), R)
        facts = {}
        lower = pos.min(axis=0) - R
        upper = pos.max(axis=0) + R
        extent = np.ptp(pos, axis=0) + 2 * R
    if len(pos) < 8:
        raise DeckError(f"domain.box = {list(dom['box'])} holds only {len(pos)} elements of radius "
                        f"{R}: expected a box at least 2 diameters wide along each axis")
    n_global = len(pos)
    low = float(lower[axis])
    high = float(upper[axis])
    near_plate = np.minimum(pos[:, axis] - radii - low, high - pos[:, axis] - radii) < NEAR_PLATE_GAP * R
    fit = pos[~near_plate]
    if len(fit) < 4 or np.linalg.matrix_rank(np.cov(fit.T) if len(fit) > 1 else np.zeros((3, 3))) < 3:
        raise DeckError(f"domain.box = {list(dom['box'])}: the elements away from the plates do not fill "
                        f"3 dimensions, so the strain cannot be fitted: expected at least 2 element layers "
                        f"across every axis and 3 along the loading axis {ld['axis']}")

    material = BeamMaterial(young=bd["young"], radius_ratio=bd["radius_ratio"],
                            poisson=bd["poisson"], damping=bd["damping"], law=bd["law"],
                            tensile_strength=bd["tensile_strength"], shear_strength=bd["shear_strength"],
                            densification_stress=bd["densification_stress"],
                            densification_p0=bd["densification_p0"])
    slab_axis = choose_axis(extent, avoid=axis) if par["slab_axis"] == "auto" else "xyz".index(par["slab_axis"])
    split = par["initial_split"]
    if split != "balanced" and len(split) != comm.size - 1:
        raise DeckError(f"parallel.initial_split has {len(split)} fractions: expected {comm.size - 1} "
                        f"(one per cut between {comm.size} ranks) or \"balanced\"")
    skin = 0.2 * R if run["skin"] == "auto" else run["skin"]
    contact_law = _contact_law_name(deck, material)
    contacts = None
    if contact_law != "none":
        contacts = ContactModel(contact_law, resolve=lambda c, e, b: _contact_params(c, deck, contact_law, b, e))
    # the one builder: slabs from a distributed bisection over a stripe of the elements per rank,
    # each rank's elements and the bonds that touch them, ghosts, the contact list; the plates and
    # the time step (bounded with the plates) are this protocol's
    sim = build(comm, System(Particles(pos, radii, dom["density"]), contacts=contacts,
                             bonds=BondModel(material, pairs, frame),
                             decomposition=Decomposition(slab_axis=slab_axis, skin=skin,
                                                         balance_every=par["balance_every"],
                                                         balance_threshold=par["balance_threshold"],
                                                         balance_by=par["balance_by"], initial_split=split)))
    elements, bonds, domain, contacts = sim.elements, sim.bonds, sim.domain, sim.contacts
    elements.flags[near_plate[elements.gid]] |= FLAG_NEAR_PLATE
    contact_params = sim.system.contacts.params if contacts is not None else {}
    reach, ghost_range = sim.reach, sim.ghost_range

    k_plate = _global_mean_axial_stiffness(comm, bonds, elements) if deck["plates"]["stiffness"] == "auto" \
        else deck["plates"]["stiffness"]
    wall_young = (comm.max(float(bonds.young.max()) if bonds.n else 0.0)
                  if deck["plates"]["young"] == "auto" else deck["plates"]["young"])
    law = _wall_law(deck["plates"], k_plate, wall_young)
    others = [a for a in range(3) if a != axis]
    lateral = []
    if deck["plates"]["lateral_walls"]:
        lateral = [[a, float(lower[a]), 1.0] for a in others] + [[a, float(upper[a]), -1.0] for a in others]
    elements.wall_h = walls.new_history(law, elements.n_total, 2 + len(lateral))
    if law.law == "hertz":
        # Hertz stiffens with overlap: bound it at an overlap of WALL_OVERLAP_BOUND R (the run
        # stops as unstable if an element ever goes deeper and the step no longer holds)
        k_plate = max(walls.stiffness(law, float(radii.max()), WALL_OVERLAP_BOUND * float(radii.max())))
    lam = eigen_bound(bonds.i, bonds.j, bonds.L0, bonds.ka, bonds.kb, bonds.kt, elements.mass,
                      elements.inertia, elements.n_owned, k_plate / elements.mass)
    dt_c = critical_time_step(comm.max(lam), comm.max(max_tau(bonds)))
    if contacts is not None:
        dt_c = min(dt_c, contact_critical_time_step(contact_law, contacts.params, radii,
                                                    dom["density"]))
    if run["dt"] == "auto":
        dt = run["dt_fraction"] * dt_c
    else:
        dt = run["dt"]
        if dt > dt_c:
            raise DeckError(f"run.dt = {dt:.6g} s is above the critical time step {dt_c:.6g} s of this "
                            f"deck: expected a value in (0, {dt_c:.6g}] or \"auto\"")
    length = high - low
    transit = length / _wave_speed(comm, bonds, elements, axis)
    ramp = _ramp_time(ld, length, transit)
    constants = CompressionConstants(
        dt=dt, dt_critical=dt_c, plate_stiffness=k_plate, ramp_time=ramp, wall_young=wall_young,
        lateral_walls=lateral, plate_low=low, plate_high=high, axis=axis, length=length,
        cross_section=_cross_section(dom, pos, axis, low, high, extent), transit_time=transit,
        analytic_young=_analytic_young(bd, frame, axis) if dom["kind"] == "ordered" else float("nan"),
        n_elements=n_global, n_bonds=len(pairs), origin=0.5 * (pos.min(axis=0) + pos.max(axis=0)),
        slab_axis=slab_axis, ghost_range=ghost_range, skin=skin, damped=bonds.damped,
        breakable=bonds.breakable, densify_p0=bonds.densify_p0, contact_law=contact_law,
        contact_params=contact_params, contact_reach=reach, domain_facts=facts)
    return _assemble(comm, deck, elements, bonds, domain, constants, steps, contacts=contacts,
                     with_plates=plates)


def _lattice_axis(frame, axis):
    """Index (0 L, 1 R, 2 T) of the frame axis along the loading ``axis``, or None (off the grid)."""
    along = np.nonzero(np.isclose(np.abs(frame[:, axis]), 1.0))[0]
    return int(along[0]) if len(along) == 1 else None


def _cross_section(dom, pos, axis, low, high, extent):
    """Initial section across the load [m^2]: the box's (compact; ordered loaded along a grid axis:
    the extent of the elements), or for an ordered grid loaded off its axes (staircase side faces)
    the section it represents: each element stands for its cubic cell (2R)^3, so the elements whose
    centres lie in the slab ``[low + 2R, high - 2R)`` (clear of the flattened faces) fill the slab's
    volume, and the section is that volume over the slab's width."""
    others = [a for a in range(3) if a != axis]
    if dom["kind"] != "ordered" or _lattice_axis(lrt_frame(dom["tilt_deg"]), axis) is not None:
        return float(extent[others[0]] * extent[others[1]])
    cell = 2.0 * dom["radius"]
    a, b = low + cell, high - cell
    inside = np.count_nonzero((pos[:, axis] >= a) & (pos[:, axis] < b))
    return float(inside * cell**3 / (b - a))


def _ramp_time(loading, length, transit):
    """The moving plate's ramp [s]: the deck's, or "auto": two periods of the slowest axial mode,
    but at most half of the travel (the moduli are fitted over the constant-speed phase after it)."""
    if loading["ramp_time"] != "auto":
        return loading["ramp_time"]
    return min(4.0 * transit, loading["strain"] * length / loading["plate_speed"])


def with_plate_speed(case, speed):
    """The freshly built ``case`` (step 0) loaded at plate speed ``speed`` [m/s] instead: deck, auto
    ramp, plates and step count follow, exactly as if it had been built with that speed (the
    elements, bonds and contacts are the same objects: run only the returned case)."""
    sim = case.sim
    if sim.step_count != 0:
        raise ValueError(f"with_plate_speed: the case has run {sim.step_count} steps: expected a new case")
    raw = raw_deck(case.deck)
    raw["loading"]["plate_speed"] = float(speed)
    deck = check_deck(COMPRESS_SCHEMA, raw)
    c = replace(case.constants, ramp_time=_ramp_time(deck["loading"], case.constants.length,
                                                     case.constants.transit_time))
    return _assemble(sim.comm, deck, sim.elements, sim.bonds, sim.domain, c, None, contacts=sim.contacts)


def _contact_law_name(deck, material):
    """The deck's element-element contact law: a name of ``CONTACT_LAWS`` or "none"."""
    law = deck["contacts"]["law"]
    if law == "auto":
        law = "hertz_mindlin" if material.breakable else "none"
    return law if law in CONTACT_LAWS else "none"


def _contact_params(comm, deck, law, bonds, elements):
    """The params dict of the deck's contacts; its "auto" values computed (collectively) from the
    bonds only when the law asks for them."""
    auto = {"young": lambda: comm.max(float(bonds.young.max()) if bonds.n else 0.0),
            "stiffness": lambda: _global_mean_axial_stiffness(comm, bonds, elements)}
    return CONTACT_LAWS[law].deck_params(deck["contacts"], auto)


def _contacts(law, params, skin, reach):
    """The ``Contacts`` of a bonded domain (no periodic cell), or None."""
    if law == "none":
        return None
    return Contacts(CONTACT_LAWS[law], law_params(law, params), skin, None, reach=reach)


def _setup(domain, contacts, elements, bonds, table=None):
    """Migration, ghosts and a new contact list (histories from ``table``, default none)."""
    if contacts is not None and table is None:
        table = contacts.table()
    if domain is None:
        if contacts is not None:
            contacts.rebuild(elements, bonds, table)
        return elements, bonds
    if contacts is None:
        return domain.setup(elements, bonds)
    elements, bonds, table = domain.setup_with_pairs(elements, bonds, table)
    contacts.rebuild(elements, bonds, table)
    return elements, bonds


def _compact_domain(comm, dom, axis, packing=None):
    """Centres, radii, bonded pairs, LRT frame and facts (solid fraction, ...) of a compact domain
    whose faces normal to the loading ``axis`` are flat.

    The packing is built on rank 0 only and broadcast: every rank then holds bitwise the same
    packing whatever the machine, and a failure reaches every rank (as a DeckError).
    """
    box, R = dom["box"], dom["radius"]
    where = f"domain.box = {list(box)} with domain.radius = {R}"
    if min(box) < compact.MIN_EDGE * R:
        raise DeckError(f"{where}: a compact packing needs every box edge at least "
                        f"{compact.MIN_EDGE:g} radii ({compact.MIN_EDGE * R:.6g} m)")
    args = (box, R, dom["dispersity"], dom["seed"], axis)
    if packing is None:
        result = None
        if comm.is_root:
            try:
                result = compact.compact_packing(*args)
            except ValueError as err:
                result = str(err)
        # the other ranks wait asleep, not in the broadcast's busy poll: a core stays free and their
        # signal handlers can run (a blocking MPI call defers them to its end)
        comm.wait_for_all()
        packing = comm.bcast(result)
        if isinstance(packing, str):
            raise DeckError(f"{where} (compact, seed {dom['seed']}, dispersity {dom['dispersity']}): "
                            f"{packing}; expected an edge along the loading axis of at least "
                            f"{compact.RELIABLE_EDGE:g} radii (the flat faces under the plates lower the "
                            f"solid fraction of short boxes)")
    elif not packing.matches(*args):
        raise ValueError(f"the packing given (box {list(packing.box)}, radius {packing.radius}, dispersity "
                         f"{packing.dispersity}, seed {packing.seed}, flat axis {packing.flat_axis}) is not "
                         f"the deck's domain and loading axis")
    try:
        pos, radii, pairs = compact.compact_domain(packing, dom["bond_gap"] * packing.mean_radius)
    except ValueError as err:
        raise DeckError(f"domain.bond_gap = {dom['bond_gap']}: {err}; expected a larger gap "
                        f"(at most 0.5)") from None
    facts = {"solid_fraction": float(4.0 / 3.0 * np.pi * np.sum(radii**3) / np.prod(box)),
             "packing_fraction": packing.solid_fraction, "mean_radius": float(np.mean(radii)),
             "max_overlap": packing.max_overlap, "removed_elements": packing.n - len(radii),
             "coordination": 2.0 * len(pairs) / len(radii)}
    return pos, radii, pairs, lrt_frame(dom["tilt_deg"]), facts


def _wall_law(plates, k_linear, young):
    """``walls.Params`` of the deck's ``[plates]`` (linear stiffness ``k_linear`` [N/m] or Hertz
    with the elements' ``young`` [Pa] against rigid walls)."""
    common = {"friction": plates["friction"], "restitution": plates["restitution"]}
    if plates["law"] == "hertz":
        return walls.Params(law="hertz", young=young, poisson=plates["poisson"], wall_young=math.inf,
                            **common)
    return walls.Params(law="linear", kn=k_linear, kt=k_linear, **common)


def _slab_comm(comm, slabs, ghost_range, skin, par):
    if comm.size == 1:
        return None
    return SlabComm(comm, slabs, ghost_range, skin, balance_every=par["balance_every"],
                    threshold=par["balance_threshold"], balance_by=par["balance_by"])


def _assemble(comm, deck, elements, bonds, domain, constants, steps, step=0, samples=(), contacts=None,
              with_plates=True):
    """The case from its state and constants; ``steps`` = total steps from the run's start (from
    the plate travel when None; 0 without plates)."""
    c = constants
    ld = deck["loading"]
    plates = None
    if with_plates:
        law = _wall_law(deck["plates"], c.plate_stiffness, c.wall_young)
        plates = Plates.pair(c.axis, c.plate_low, c.plate_high, ld["plate_speed"],
                             c.plate_stiffness, c.ramp_time, law=law, lateral=c.lateral_walls)
        if steps is None:
            t_end = plates.time_to_travel(ld["strain"] * c.length)
            if not math.isfinite(t_end / c.dt):
                raise DeckError("loading.strain, loading.plate_speed, run.dt: the loading never ends")
            steps = max(1, math.ceil(t_end / c.dt - 1e-9))
    sim = Simulation(comm, elements, bonds, plates, c.dt, domain=domain, contacts=contacts)
    sim.step_count = int(step)
    sim.time = sim.step_count * sim.dt
    if plates is not None:
        plates.move_to(sim.time)
    reducer = Reducer(comm, origin=c.origin)
    t0 = time.perf_counter()
    compile_step_kernels(sim)
    return CompressionCase(sim=sim, reducer=reducer, deck=deck, constants=c, n_steps=int(steps or 0),
                           samples=list(samples), compile_seconds=time.perf_counter() - t0)


def compile_step_kernels(sim):
    """Compile (or load from Numba's cache) the kernels of a time step, the stability check and
    a sample of ``sim`` by running two steps of a throwaway copy of one of its bonds (its two
    ends, the plates, an empty contact list of the same law), so that the run's timing, and the
    ``element_steps_per_second`` of the summary, count no compilation. Numba compiles
    per argument types and compile-time flags, not sizes: the copy has the run's. Local (no
    collective: the copy has no slab layer, whose few kernels still compile in the run); the
    state of ``sim`` is not touched. A few milliseconds once compiled."""
    e, b = sim.elements, sim.bonds
    if b is not None and b.n:
        bonds = Bonds.unpack([b.pack(np.array([0]))], **b.flags())
        rows = np.array([b.i[0], b.j[0]])
    else:
        bonds = Bonds.empty()
        rows = np.arange(min(e.n_total, 2))
    elements = Elements.unpack([e.pack(rows)], len(rows))
    bonds.relink(elements.gid)
    c = sim.contacts
    contacts = None if c is None else Contacts(c.law, c.params, c.skin, None, reach=c.cut,
                                               reproducible=c.reproducible)
    tmp = Simulation(sim.comm, elements, bonds, copy.deepcopy(sim.plates), sim.dt, contacts=contacts)
    tmp.step_count, tmp.time, tmp._clock = sim.step_count, sim.time, sim._clock
    if contacts is not None:
        tmp.rebuild_contacts()
    tmp.compute_forces()
    tmp.step(with_energy=True)
    tmp.step(with_energy=False)
    tmp._check_finite()
    strain_sums(elements.x, elements.x0, elements.flags, elements.n_owned, np.zeros(3), np.empty(STRAIN_SUMS))


def checkpoint_payload(case):
    """(groups, series, attrs) for ``pardem.io.checkpoint.write_checkpoint`` (every rank): the
    simulation's state (``pardem.engine.snapshot.payload``), the deck, the constants and the samples."""
    groups, attrs = snapshot.payload(case.sim, {"deck": case.deck, "constants": case.constants.as_dict(),
                                                "slab_axis": case.constants.slab_axis})
    return groups, samples_to_columns(case.samples), attrs


SAMPLE_COUNTS = ("bonds_broken", "bonds_broken_step", "bonds_yielded")


def samples_to_columns(samples):
    keys = ("step", "time", "plate_displacement", "force_fixed", "force_moving") + SAMPLE_COUNTS
    cols = {k: np.array([s[k] for s in samples]) for k in keys}
    cols["H"] = np.array([s["H"] for s in samples]).reshape(-1, 3, 3)
    return cols


def columns_to_samples(cols):
    out = []
    for k in range(len(cols["step"])):
        H = np.array(cols["H"][k])
        out.append({"step": int(cols["step"][k]), "time": float(cols["time"][k]),
                    "plate_displacement": float(cols["plate_displacement"][k]),
                    "force_fixed": float(cols["force_fixed"][k]), "force_moving": float(cols["force_moving"][k]),
                    "H": H, "eps": 0.5 * (H + H.T),
                    # series of checkpoints written before bonds could break hold no counts
                    **{c: int(cols[c][k]) if c in cols else 0 for c in SAMPLE_COUNTS}})
    return out


def restore_case(comm, deck, path, steps=None, meta=None):
    """The case continued from checkpoint ``path`` on this communicator (any number of ranks).

    On the rank count that wrote it, every rank reads back exactly its rows and its slabs, so the
    continued run is bit-for-bit the uninterrupted one; on another count, slabs are re-cut and the
    elements migrate to their new owners. CheckpointError for an unusable file, DeckError when the
    deck would change the physics.
    """
    meta = checkpoint.inspect(path, comm=comm) if meta is None else meta   # collective verification
    if steps is not None and steps < int(meta["step"]):
        raise DeckError(f"--steps {steps} is before the checkpoint's step {int(meta['step'])}: --steps "
                        f"counts the run's total steps from its start")
    diffs = physics_differences(upgrade(meta["deck"]), deck)
    if diffs:
        name, old, new = diffs[0]
        raise DeckError(f"{name} = {new!r} differs from the checkpoint's {old!r}: a restart may change "
                        f"only the run length (loading.strain, --steps) and the output, checkpoint and "
                        f"parallel settings")
    c = CompressionConstants.from_dict(meta["constants"])
    par = deck["parallel"]
    slab_axis = c.slab_axis if par["slab_axis"] == "auto" else "xyz".index(par["slab_axis"])
    contacts = _contacts(c.contact_law, c.contact_params, c.skin, c.contact_reach)
    parts = restart.read(comm, path, meta, slab_axis, contacts=contacts,
                         slab_comm=lambda slabs: _slab_comm(comm, slabs, c.ghost_range, c.skin, par),
                         bond_options={"damped": bool(c.damped), "breakable": c.breakable,
                                       "densify_p0": c.densify_p0})
    case = _assemble(comm, deck, parts.elements, parts.bonds, parts.domain, c, steps, step=int(meta["step"]),
                     samples=columns_to_samples(meta["series"]), contacts=contacts)
    snapshot.resume(case.sim, meta, parts.same)
    return case


def _global_mean_axial_stiffness(comm, bonds, elements):
    once = bonds.counted_once(elements.n_owned)
    s = comm.sum([bonds.ka[once].sum(), once.sum()])
    return float(s[0] / s[1])


def _wave_speed(comm, bonds, elements, axis):
    """Axial wave speed ``L0 sqrt(k / m)`` [m/s] of the bond chains closest to the loading axis.

    A global mean (every rank gets the same value, so the plate moves identically everywhere).
    """
    once = bonds.counted_once(elements.n_owned)
    i, j = bonds.i[once], bonds.j[once]
    m = 0.5 * (elements.mass[i] + elements.mass[j])
    d = np.abs(elements.x[j, axis] - elements.x[i, axis]) / bonds.L0[once]
    d_max = comm.max(float(d.max()) if len(d) else 0.0)
    along = d >= d_max - 1e-6
    c = bonds.L0[once][along] * np.sqrt(bonds.ka[once][along] / m[along])
    s = comm.sum([c.sum(), along.sum()])
    return float(s[0] / s[1])


def _analytic_young(bd, frame, axis):
    """``pi/4 E r_adim^2`` of the ordered lattice loaded along a lattice axis (docs/physics.md section 6)."""
    k = _lattice_axis(frame, axis)   # which of L, R, T lies along the loading axis
    if k is None:
        return float("nan")
    E = np.broadcast_to(np.asarray(bd["young"], dtype=float), (3,))[k]
    r = np.broadcast_to(np.asarray(bd["radius_ratio"], dtype=float), (3,))[k]
    return float(np.pi / 4.0 * E * r * r)


QUASI_STATIC_TRANSITS = 4.0   # loading shorter than this many wave transits is dynamic


def loading_warning(case):
    """A warning line when the loading is too fast to be quasi-static, else None."""
    duration = case.n_steps * case.sim.dt
    if not case.constants.transit_time > 0.0:
        return None
    ratio = duration / case.constants.transit_time
    if not (math.isfinite(ratio) and ratio > 0.0) or ratio >= QUASI_STATIC_TRANSITS:
        return None
    return (f"warning: the loading lasts {duration:.3g} s, only {ratio:.2g} times the {case.constants.transit_time:.3g} s "
            f"an axial wave takes to cross the domain: the response is dynamic, not quasi-static; "
            f"lower loading.plate_speed by a factor {QUASI_STATIC_TRANSITS / ratio:.2g} or more")


class SeriesSampler:
    """Operation: samples the reducer on the steps of ``trigger`` (an int period [steps] or a
    ``Trigger``) and after the last step of every run (``at_end``: the series ends on the final
    state), and hands the sample to sinks; a step already sampled is not sampled again."""
    at_end = True

    def __init__(self, case, trigger, sinks=()):
        self.case = case
        self.trigger = as_trigger(trigger)
        self.sinks = list(sinks)

    def __call__(self, sim):
        if self.case.samples and self.case.samples[-1]["step"] == sim.step_count:
            return
        s = self.case.reducer.sample(sim)
        self.case.samples.append(s)
        for sink in self.sinks:
            sink(s)


MIN_FIT_SAMPLES = 3   # samples after the ramp needed to fit the quasi-static modulus


def measure(case):
    """Moduli from the samples.

    ``young_modulus``: slope of the mean plate force ``(F_fixed + F_moving) / 2`` against the axial
    strain over the constant-speed phase (after the ramp), divided by the section. The mean of the
    two plate forces cancels the domain's inertial force to first order and the slope removes the
    constant viscous stress of the bond damping, so this is the quasi-static modulus.
    ``young_modulus_secant``: W's definition, fixed-plate force over section and strain at the end.
    Poisson ratios, the strain tensor and the bond counts are those of the last sample;
    ``peak_stress`` [Pa] is the largest fixed-plate force over the section, at ``strain_at_peak``
    (axial strain, compression positive).
    """
    a = case.constants.axis
    last = case.samples[-1]
    E_sec, nus = young_and_poisson(last["eps"], last["force_fixed"], a, case.constants.cross_section)
    t = np.array([s["time"] for s in case.samples])
    eps = np.array([-s["eps"][a, a] for s in case.samples])
    F = np.array([0.5 * (s["force_fixed"] + s["force_moving"]) for s in case.samples])
    keep = t >= case.sim.plates.ramp_time
    if keep.sum() >= MIN_FIT_SAMPLES and np.ptp(eps[keep]) > 0:
        E_tan = float(np.polyfit(eps[keep], F[keep], 1)[0] / case.constants.cross_section)
    else:
        E_tan = float("nan")
    peak = int(np.argmax([s["force_fixed"] for s in case.samples]))
    return {"young_modulus": E_tan, "young_modulus_secant": E_sec, "poisson_ratios": nus,
            "strain_tensor": last["eps"], "plate_force": last["force_fixed"],
            "plate_force_moving": last["force_moving"],
            "peak_stress": case.samples[peak]["force_fixed"] / case.constants.cross_section,
            "strain_at_peak": float(eps[peak]),
            "bonds_broken": last["bonds_broken"], "bonds_yielded": last["bonds_yielded"],
            "samples_after_ramp": int(keep.sum())}


# an element whose gap to a plate is below this fraction of the largest radius touches it at the start
# (the plates lie on the outermost element surfaces, to round-off)
TOUCHING = 1e-9


def static_modulus(case, touch=None):
    """Young's modulus [Pa] along the loading axis of the case's bond network from its static linear
    response between the plates (``pardem.physics.beam_static``): what ``measure`` finds dynamically,
    without time stepping, damping or plate dynamics.

    ``touch`` [m]: the elements whose gap to a plate is below it are tied to that plate; default
    ``TOUCHING`` of the largest radius, the elements touching at the start (the run closes the gaps
    below its plate travel: pass the travel for the tangent of its final contact set, approximately:
    a few elements tied across a gap may be pulled, which is not checked). Strain: the fit of
    ``measure`` (``reducer.strain_sums``, the elements not flagged near a plate); force: the fixed
    plate's; section: ``constants.cross_section``. One rank, intact bonds. ValueError for plates the
    static model does not describe (Hertz, frictional, lateral walls), or when a plate pulls an
    element it touches at the start (it would leave the plate).
    """
    e, b, c, plates = case.sim.elements, case.sim.bonds, case.constants, case.sim.plates
    n = e.n_owned
    if b.n and max(b.i.max(), b.j.max()) >= n:
        raise ValueError("static_modulus: a bond reaches a ghost element; run it on one rank")
    if plates.law.law != "linear" or plates.law.friction != 0.0 or len(plates.lateral):
        raise ValueError("static_modulus: expected linear frictionless plates without lateral walls, got "
                         f"{plates.law.law} plates, friction {plates.law.friction}, {len(plates.lateral)} "
                         "lateral walls")
    R = e.radius[:n]
    touch = TOUCHING * float(R.max()) if touch is None else touch
    k = b.intact
    r = beam_static.plate_response(e.x0[:n], R, b.i[k], b.j[k], b.L0[k], b.ka[k], b.kb[k], b.kt[k], c.axis,
                                   c.plate_low, c.plate_high, c.plate_stiffness, touch)
    touching = r.gap < TOUCHING * float(R.max())
    if (r.pulled & touching).any():
        raise ValueError(f"static_modulus: the plates pull {int((r.pulled & touching).sum())} elements they "
                         "touch at the start: the linear ties are not the frictionless contact problem")
    sums = np.empty(STRAIN_SUMS)
    strain_sums(e.x0[:n] + r.u, e.x0[:n], e.flags[:n], n, c.origin, sums)
    H = gradient_from_sums(sums)
    return r.force_low / (c.cross_section * -H[c.axis, c.axis])
