"""The compression test between plates: build the case from a deck, run it, measure the moduli.

Used by the compress driver and by the tests; knows nothing of files (the driver writes them).
"""
import math
import time
from dataclasses import dataclass, field

import numpy as np

from pardem.bonding import BeamMaterial, make_bonds
from pardem.config import DeckError
from pardem.domains.ordered import ordered_lattice
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import Slabs, choose_axis
from pardem.physics.timestep import critical_time_step, eigen_bound, max_tau
from pardem.reducer import Reducer, young_and_poisson
from pardem.simulation import Simulation
from pardem.state import FLAG_NEAR_PLATE, Elements, Plates

NEAR_PLATE_GAP = 0.5   # elements closer than this many radii to a plate at the start: not in the strain fit


@dataclass
class CompressionCase:
    sim: Simulation
    reducer: Reducer
    axis: int
    cross_section: float       # initial section normal to the axis [m^2]
    length: float              # initial plate gap [m]
    dt_critical: float
    n_steps: int
    analytic_young: float      # pi/4 E r^2 along the axis, or nan where it does not apply
    transit_time: float        # time for an axial wave to cross the domain [s]
    n_elements: int            # global counts
    n_bonds: int
    slab_axis: int
    frame: np.ndarray
    samples: list = field(default_factory=list)


GHOST_STRETCH = 1.25   # bonds may stretch by 25 % before they would outgrow the ghost layer


def build_case(comm, deck, steps=None):
    """Elements, bonds, plates and time step of the deck's compression test on this rank.

    Every rank computes the lattice geometry (cheap), keeps its slab's elements and the bonds that
    touch them, then the slab layer builds the ghosts. DeckError on a bad time step or split.
    """
    dom, bd, ld, run, par = deck["domain"], deck["bonds"], deck["loading"], deck["run"], deck["parallel"]
    R = dom["radius"]
    pos, pairs, frame = ordered_lattice(dom["box"], R, dom["tilt_deg"])
    if len(pos) < 8:
        raise DeckError(f"domain.box = {list(dom['box'])} holds only {len(pos)} elements of radius "
                        f"{R}: expected a box at least 2 diameters wide along each axis")
    n_global = len(pos)
    gids = np.arange(n_global, dtype=np.int64)
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    bond_gids = np.arange(len(pairs), dtype=np.int64)
    axis = "xyz".index(ld["axis"])
    low = float(np.min(pos[:, axis]) - R)
    high = float(np.max(pos[:, axis]) + R)
    extent = np.ptp(pos, axis=0) + 2 * R
    near_plate = np.minimum(pos[:, axis] - R - low, high - pos[:, axis] - R) < NEAR_PLATE_GAP * R

    # slabs: cuts from a distributed bisection over a stripe of the elements per rank
    slab_axis = choose_axis(extent, avoid=axis) if par["slab_axis"] == "auto" else "xyz".index(par["slab_axis"])
    split = par["initial_split"]
    if split != "balanced" and len(split) != comm.size - 1:
        raise DeckError(f"parallel.initial_split has {len(split)} fractions: expected {comm.size - 1} "
                        f"(one per cut between {comm.size} ranks) or \"balanced\"")
    stripe = slice(comm.rank, None, comm.size)
    slabs = Slabs.balanced(comm, slab_axis, pos[stripe, slab_axis], gids[stripe],
                           fractions=None if split == "balanced" else split)
    owned = slabs.owner(pos[:, slab_axis], gids) == comm.rank
    touch = owned[pairs[:, 0]] | owned[pairs[:, 1]]
    partners = np.setdiff1d(pairs[touch].ravel(), np.nonzero(owned)[0])
    rows = np.concatenate([np.nonzero(owned)[0], partners])
    local_row = np.full(n_global, -1, dtype=np.int64)
    local_row[rows] = np.arange(len(rows))
    elements = Elements.from_spheres(pos[rows], R, dom["density"], gids[rows])
    elements.n_owned = int(owned.sum())
    elements.flags[near_plate[rows]] |= FLAG_NEAR_PLATE
    material = BeamMaterial(young=bd["young"], radius_ratio=bd["radius_ratio"],
                            poisson=bd["poisson"], damping=bd["damping"], law=bd["law"])
    bonds = make_bonds(elements, local_row[pairs[touch]], material, frame, gids=bond_gids[touch])

    domain = None
    if comm.size > 1:
        skin = 0.2 * R if par["skin"] == "auto" else par["skin"]
        L_max = comm.max(float(bonds.L0.max()) if bonds.n else 0.0)
        domain = SlabComm(comm, slabs, GHOST_STRETCH * L_max + skin, skin,
                          balance_every=par["balance_every"], threshold=par["balance_threshold"],
                          balance_by=par["balance_by"])
        elements, bonds = domain.setup(elements, bonds)

    k_plate = _global_mean_axial_stiffness(comm, bonds, elements) if deck["plates"]["stiffness"] == "auto" \
        else deck["plates"]["stiffness"]
    lam = eigen_bound(bonds.i, bonds.j, bonds.L0, bonds.ka, bonds.kb, bonds.kt, elements.mass,
                      elements.inertia, elements.n_owned, k_plate / elements.mass)
    dt_c = critical_time_step(comm.max(lam), comm.max(max_tau(bonds)))
    if run["dt"] == "auto":
        dt = run["dt_fraction"] * dt_c
    else:
        dt = run["dt"]
        if dt > dt_c:
            raise DeckError(f"run.dt = {dt:.6g} s is above the critical time step {dt_c:.6g} s of this "
                            f"deck: expected a value in (0, {dt_c:.6g}] or \"auto\"")
    length = high - low
    transit = length / _wave_speed(comm, bonds, elements, axis)
    ramp = ld["ramp_time"]
    if ramp == "auto":
        # two periods of the slowest axial mode, but at most half of the travel (the moduli are
        # fitted over the constant-speed phase that follows)
        ramp = min(4.0 * transit, ld["strain"] * length / ld["plate_speed"])
    plates = Plates.pair(axis, low, high, ld["plate_speed"], k_plate, ramp)
    t_end = plates.time_to_travel(ld["strain"] * length)
    n_steps = steps if steps is not None else max(1, math.ceil(t_end / dt - 1e-9))
    others = [a for a in range(3) if a != axis]
    section = float(extent[others[0]] * extent[others[1]])
    analytic = _analytic_young(bd, frame, axis)
    sim = Simulation(comm, elements, bonds, plates, dt, domain=domain)
    reducer = Reducer(comm, origin=0.5 * (pos.min(axis=0) + pos.max(axis=0)))
    return CompressionCase(sim=sim, reducer=reducer, axis=axis, cross_section=section, length=length,
                           dt_critical=dt_c, n_steps=n_steps, analytic_young=analytic,
                           transit_time=transit, frame=frame, n_elements=n_global,
                           n_bonds=len(pairs), slab_axis=slab_axis)


def _counted_once(bonds, elements):
    """Mask of the bonds this rank counts in global sums: those whose first end it owns."""
    return bonds.i < elements.n_owned


def _global_mean_axial_stiffness(comm, bonds, elements):
    once = _counted_once(bonds, elements)
    s = comm.sum([bonds.ka[once].sum(), once.sum()])
    return float(s[0] / s[1])


def _wave_speed(comm, bonds, elements, axis):
    """Axial wave speed ``L0 sqrt(k / m)`` [m/s] of the bond chains closest to the loading axis.

    A global mean (every rank gets the same value, so the plate moves identically everywhere).
    """
    once = _counted_once(bonds, elements)
    i, j = bonds.i[once], bonds.j[once]
    m = 0.5 * (elements.mass[i] + elements.mass[j])
    d = np.abs(elements.x[j, axis] - elements.x[i, axis]) / bonds.L0[once]
    d_max = comm.max(float(d.max()) if len(d) else 0.0)
    along = d >= d_max - 1e-6
    c = bonds.L0[once][along] * np.sqrt(bonds.ka[once][along] / m[along])
    s = comm.sum([c.sum(), along.sum()])
    return float(s[0] / s[1])


def _analytic_young(bd, frame, axis):
    """``pi/4 E r_adim^2`` of the ordered lattice loaded along a lattice axis (PHYSICS.md section 6)."""
    along = np.nonzero(np.isclose(np.abs(frame[:, axis]), 1.0))[0]
    if len(along) != 1:
        return float("nan")
    k = int(along[0])   # which of L, R, T lies along the loading axis
    E = np.broadcast_to(np.asarray(bd["young"], dtype=float), (3,))[k]
    r = np.broadcast_to(np.asarray(bd["radius_ratio"], dtype=float), (3,))[k]
    return float(np.pi / 4.0 * E * r * r)


QUASI_STATIC_TRANSITS = 4.0   # loading shorter than this many wave transits is dynamic


def loading_warning(case):
    """A warning line when the loading is too fast to be quasi-static, else None."""
    duration = case.n_steps * case.sim.dt
    ratio = duration / case.transit_time
    if ratio >= QUASI_STATIC_TRANSITS:
        return None
    return (f"warning: the loading lasts {duration:.3g} s, only {ratio:.2g} times the {case.transit_time:.3g} s "
            f"an axial wave takes to cross the domain: the response is dynamic, not quasi-static; "
            f"lower loading.plate_speed by a factor {QUASI_STATIC_TRANSITS / ratio:.2g} or more")


class SeriesSampler:
    """Operation: samples the reducer every ``every`` steps and hands the sample to sinks."""

    def __init__(self, case, every, sinks=()):
        self.case = case
        self.every = max(1, int(every))
        self.sinks = list(sinks)

    def __call__(self, sim):
        if self.case.samples and self.case.samples[-1]["step"] == sim.step_count:
            return
        s = self.case.reducer.sample(sim)
        self.case.samples.append(s)
        for sink in self.sinks:
            sink(s)


class Progress:
    """Sink printing one progress line every ``seconds`` (rank 0 only)."""

    def __init__(self, case, n_elements, seconds, stream):
        self.case = case
        self.n_elements = n_elements
        self.seconds = seconds
        self.stream = stream
        self.t0 = time.perf_counter()
        self.last = -math.inf
        self.end = case.sim.step_count + case.n_steps

    def __call__(self, s):
        now = time.perf_counter()
        if now - self.last < self.seconds and s["step"] < self.end:
            return
        self.last = now
        done = s["step"] - (self.end - self.case.n_steps)
        rate = done * self.n_elements / max(now - self.t0, 1e-9)
        eta = (self.end - s["step"]) * self.n_elements / rate if rate > 0 else float("nan")
        eps = s["eps"][self.case.axis, self.case.axis]
        self.stream.write(
            f"step {s['step']:>8d}/{self.end} ({100.0 * done / self.case.n_steps:5.1f} %)  "
            f"t = {s['time']:.4e} s  eps = {eps:+.4e}  F = {s['force_fixed']:.4e} N  "
            f"{rate:.3e} element-steps/s  ETA {eta:6.1f} s\n")
        self.stream.flush()


def measure(case):
    """Moduli from the samples.

    ``young_modulus``: slope of the mean plate force ``(F_fixed + F_moving) / 2`` against the axial
    strain over the constant-speed phase (after the ramp), divided by the section. The mean of the
    two plate forces cancels the domain's inertial force to first order and the slope removes the
    constant viscous stress of the bond damping, so this is the quasi-static modulus.
    ``young_modulus_secant``: W's definition, fixed-plate force over section and strain at the end.
    Poisson ratios and the strain tensor are those of the last sample.
    """
    a = case.axis
    last = case.samples[-1]
    E_sec, nus = young_and_poisson(last["eps"], last["force_fixed"], a, case.cross_section)
    t = np.array([s["time"] for s in case.samples])
    eps = np.array([-s["eps"][a, a] for s in case.samples])
    F = np.array([0.5 * (s["force_fixed"] + s["force_moving"]) for s in case.samples])
    keep = t >= case.sim.plates.ramp_time
    if keep.sum() >= 3 and np.ptp(eps[keep]) > 0:
        E_tan = float(np.polyfit(eps[keep], F[keep], 1)[0] / case.cross_section)
    else:
        E_tan = float("nan")
    return {"young_modulus": E_tan, "young_modulus_secant": E_sec, "poisson_ratios": nus,
            "strain_tensor": last["eps"], "plate_force": last["force_fixed"],
            "plate_force_moving": last["force_moving"]}
