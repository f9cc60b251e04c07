"""The anisotropy study (W's central experiment): domain anisotropy degrees against bond ratios.

For each domain kind (``ordered``, ``compact``) and each anisotropy law (``TOR``, ``hankinson``,
``linear``, ``spherical``) the bond ratio ``E_L/E_R`` is swept (default 1, 5, 10, 15, 20, 25) with
``E_R`` and ``E_T`` fixed by the deck's ``bonds.young`` (default 100 and 20 MPa, so that
``E_L/E_T = 5 E_L/E_R``); each domain is compressed along L = x, R = y and T = z and the domain
anisotropy degrees ``E_L^D/E_R^D`` and ``E_L^D/E_T^D`` are reported as mean and standard deviation
over the realisations (realisation k of a compact domain uses ``domain.seed = base seed + k``;
the ordered lattice is deterministic, so each of its cases runs once and its std is 0).

Off-axis sweep: every law at one bond ratio (default the largest swept), compressed along x with the
LRT frame tilted by ``xi`` = 0..90 deg about z (the ordered grid tilts with the frame; a compact
packing stays, only its frame rotates), compared with Hankinson's prediction
``E0 E90 / (E0 sin^2 xi + E90 cos^2 xi)`` from the measured means E(0) and E(90).

Loading rate: each case moves its plate so that the nominal strain is reached after ``transits``
axial wave transits (``CompressionCase.transit_time``) plus half the ramp; the modulus is the
quasi-static slope of ``pardem.protocols.compression.measure``. The strain is small (the response is linear).

Failed measurements: a case is ``ok`` only if both plates still push at the end, the loaded faces
stay flat and normal to the load (``|H[a, b]| <= FACE_TILT_MAX |H[a, a]|``, b != a: the domain did
not rotate or slide between the frictionless plates) and the loading was quasi-static (the two
plate forces agree within ``PLATE_MISMATCH_MAX`` and the slopes over the two halves of the fitted
phase within ``SLOPE_DRIFT_MAX``; else the case is rerun ``SLOWER`` times slower, at most
``RETRIES`` times). The secant modulus is recorded, not used: the first contacts of a compact
domain with the plates make it differ from the slope. Failed cases (``lost_contact``, ``rotated``, ``dynamic``, ``unstable``,
``bad_input``) are left out of the statistics and counted in each row's ``n_failed``.

Off-axis ordered lattices: a grid tilted by any angle but 0, 45 and 90 deg cut to a box ends in
staircases, and a plate would touch one row of spheres per face: two offset lines of contact make a
couple that turns the domain between frictionless plates (it was flagged ``rotated`` or
``lost_contact``). The faces under the plates are therefore made flat (``domains.ordered``: the
elements within one radius of each loaded face are moved onto it), as the compact builder does. The
plates stay frictionless and the sides free, because the off-axis modulus that Hankinson's formula and
the orthotropic transformation describe is the one under uniaxial stress, where the domain shears as
it shortens (the compliance's tension-shear coupling): plate friction would block that shear (an
end-constrained, stiffer modulus), lateral walls would confine the domain, and periodic lateral
boundaries need a tilt with a rational tangent and hold the lateral strain (and so the stress) at the
period's. The finite lattice's free staircase side faces soften it by a boundary layer that scales
as 1/W (W rows across; about 12 %, 6 %, 3 % at 45 deg for W = 9, 19, 39). The slowest wave of a tilted
lattice is its shear wave, so its loading time is scaled by ``transit_factor``.

Compact packings: the builder makes the faces under the plates flat, so a realisation (one seed) has
one packing per loading axis; each is built once (``realisation_packing``) and shared by every law,
ratio and tilt loaded along that axis. E_L^D/E_R^D of a realisation thus compares the x- and y-flat
packings of one seed.

Parallel: independent cases run on one rank each (the engine on a single-rank communicator); all
cases of one compact realisation run on the same rank one after the other (its packings are built
there once); ordered cases are spread one by one. Groups are dealt to the ranks by decreasing
estimated cost (longest processing time first). Results are gathered on rank 0 and, every case
being deterministic, are the same for any number of ranks.

Runtime: see ``pardem.drivers.anisotropy``.
"""
import contextlib
import copy
import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from pardem.protocols.calibration import as_lrt, lattice_shear_modulus, lattice_young
from pardem.protocols.compression import SeriesSampler, build_case, measure, with_plate_speed
from pardem.config import DeckError, check_deck, raw_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.domains.compact import compact_packing
from pardem.errors import InstabilityError

LAWS = ("TOR", "hankinson", "linear", "spherical")      # W's four laws: the study's default
ALL_LAWS = LAWS + ("spherical_normalised",)             # --laws may also pick the normalised variant
KINDS = ("ordered", "compact")
AXES = ("x", "y", "z")          # L, R, T when the frame is not tilted
DEFAULT_RATIOS = (1.0, 5.0, 10.0, 15.0, 20.0, 25.0)
# loading time in axial wave transits: the slope modulus is within about 2 % of its slow-loading
# limit after 4 transits, 0.7 % after 8, 0.3 % after 16 (ordered lattice at 45 deg, compact domain)
DEFAULT_TRANSITS = 8.0

# |dU_a/dX_b| / |dU_a/dX_a| allowed for b != a (flat loaded faces). The static linear response of a
# tilted 9-row lattice between flat frictionless plates has up to 0.66 (20 deg: the interior warps
# beside the staircase side faces; 0.03 on 39 rows); a domain turning or sliding between the plates
# (before its loaded faces were made flat) showed 11 to 200.
FACE_TILT_MAX = 2.0
# Quasi-static: the two plate forces agree within PLATE_MISMATCH_MAX at the end (their difference is
# the domain's inertia) and the slopes over the two halves of the fitted phase within SLOPE_DRIFT_MAX
# (an oscillation left by the ramp would bias the fitted slope). Weakly damped slow modes keep a few %
# of mismatch in compact domains long after the slope has converged, hence 10 %.
PLATE_MISMATCH_MAX = 0.10
SLOPE_DRIFT_MAX = 0.05
SLOWER = 4.0                    # loading time factor of a rerun when a case was dynamic
RETRIES = 2

# The study's built-in deck (the same as drivers/anisotropy_study.toml; a test checks it).
STUDY_DECK = {
    "domain": {"box": [0.0055, 0.0055, 0.0055], "radius": 0.25e-3, "density": 1000.0, "dispersity": 0.3},
    "bonds": {"young": [100e6, 100e6, 20e6], "radius_ratio": 1.0, "poisson": 0.3, "damping": 0.05},
    "loading": {"strain": 0.002, "ramp_time": "auto"},
    "run": {"dt": "auto", "dt_fraction": 0.5},
}
# --quick: a box of 18 radii (9^3 ordered, about 740 compact elements: the compact builder needs the
# wide size range to jam above 0.63 in so small a box), 2 ratios, 2 realisations, xi = 0, 45, 90
QUICK_SET = ["domain.box=[0.0045, 0.0045, 0.0045]", "domain.radius=0.25e-3", "domain.dispersity=0.45"]
QUICK_PLAN = {"ratios": (1.0, 5.0), "realisations": 2, "xi_step": 45.0}


@dataclass(frozen=True)
class StudyPlan:
    """What the study runs (all validated by the driver).

    ratios : bond ratios E_L/E_R [-]; E_R, E_T [Pa] fixed; realisations : compact realisations;
    xi_step : off-axis step [deg] (0 = no off-axis sweep); offaxis_ratio : E_L/E_R of the sweep;
    transits : loading time in axial wave transits; base_seed : seed of realisation 0;
    steps : at most this many steps per case (None: the loading of ``transits``).
    """
    kinds: tuple
    laws: tuple
    ratios: tuple
    E_R: float
    E_T: float
    realisations: int = 10
    xi_step: float = 10.0
    offaxis_ratio: float = 25.0
    transits: float = DEFAULT_TRANSITS
    base_seed: int = 0
    steps: int = None

    def xis(self):
        if not self.xi_step:
            return ()
        n = int(round(90.0 / self.xi_step))
        return tuple(float(k * self.xi_step) for k in range(n + 1))

    def runs(self, kind):
        """Realisations actually run: the ordered lattice is deterministic, so once."""
        return 1 if kind == "ordered" else self.realisations


@dataclass(frozen=True)
class Case:
    """One compression: domain kind and realisation, law, bond ratio E_L/E_R, loading axis, tilt [deg]."""
    kind: str
    realisation: int
    law: str
    ratio: float
    axis: str
    tilt_deg: float = 0.0


def plan_cases(plan):
    """Groups of cases; the cases of one group share one realisation and run on one rank in order.

    A ratio-sweep case and an off-axis case that are the same compression (xi = 0 along x) are one case.
    """
    groups = []
    for kind in plan.kinds:
        for k in range(plan.runs(kind)):
            cases = [Case(kind, k, law, q, axis) for law in plan.laws for q in plan.ratios for axis in AXES]
            cases += [Case(kind, k, law, plan.offaxis_ratio, "x", xi) for law in plan.laws for xi in plan.xis()]
            cases = list(dict.fromkeys(cases))
            if kind == "ordered":    # cheap to build: spread case by case
                groups += [[c] for c in cases]
            else:
                groups.append(cases)
    return groups


def owner(plan, n_ranks, kind, realisation):
    """The lowest rank that runs cases of ``kind``'s realisation (all of them for a compact one)."""
    groups = plan_cases(plan)
    for rank, part in enumerate(assign(groups, n_ranks, plan)):
        if any(c.kind == kind and c.realisation == realisation for g in part for c in groups[g]):
            return rank
    raise ValueError(f"no {kind} realisation {realisation} in the plan")


def estimated_cost(case, plan):
    """Relative cost of a case: steps ~ sqrt(stiffest / loaded-direction bond stiffness)."""
    E = (case.ratio * plan.E_R, plan.E_R, plan.E_T)
    along = {"x": E[0] if case.tilt_deg == 0 else min(E[:2]), "y": E[1], "z": E[2]}[case.axis]
    return math.sqrt(max(E) / along)


def assign(groups, n_ranks, plan):
    """Group indices per rank: longest estimated first, each to the least loaded rank (deterministic)."""
    cost = [sum(estimated_cost(c, plan) for c in g) for g in groups]
    load = [0.0] * n_ranks
    mine = [[] for _ in range(n_ranks)]
    for g in sorted(range(len(groups)), key=lambda g: (-cost[g], g)):
        r = min(range(n_ranks), key=lambda r: (load[r], r))
        mine[r].append(g)
        load[r] += cost[g]
    return [sorted(m) for m in mine]


def bond_moduli(deck):
    """(E_R, E_T) [Pa] of the deck's ``bonds.young`` (a number means E_R = E_T)."""
    E = np.broadcast_to(np.asarray(deck["bonds"]["young"], dtype=float), (3,))
    return float(E[1]), float(E[2])


def case_deck(deck, plan, case, plate_speed=None):
    """The checked compress deck of ``case``: the study deck with the case's kind, seed, tilt, law,
    bond moduli [ratio E_R, E_R, E_T], loading axis and (if given) plate speed [m/s]."""
    raw = raw_deck(copy.deepcopy(deck))
    raw["domain"]["kind"] = case.kind
    raw["domain"]["tilt_deg"] = case.tilt_deg
    if case.kind != "ordered":
        raw["domain"]["seed"] = plan.base_seed + case.realisation
    raw["bonds"]["young"] = [case.ratio * plan.E_R, plan.E_R, plan.E_T]
    raw["bonds"]["law"] = case.law
    raw["loading"]["axis"] = case.axis
    if plate_speed is not None:
        raw["loading"]["plate_speed"] = plate_speed
    return check_deck(COMPRESS_SCHEMA, raw)


def _slope_drift(case):
    """|s1/s2 - 1| of the force-strain slopes over the two halves of the phase ``measure`` fits."""
    a = case.constants.axis
    t = np.array([s["time"] for s in case.samples])
    eps = np.array([-s["eps"][a, a] for s in case.samples])
    F = np.array([0.5 * (s["force_fixed"] + s["force_moving"]) for s in case.samples])
    keep = np.nonzero(t >= case.sim.plates.ramp_time)[0]
    h = len(keep) // 2
    if h < 3 or np.ptp(eps[keep[:h + 1]]) == 0 or np.ptp(eps[keep[h:]]) == 0:
        return math.inf
    first = np.polyfit(eps[keep[:h + 1]], F[keep[:h + 1]], 1)[0]
    second = np.polyfit(eps[keep[h:]], F[keep[h:]], 1)[0]
    return float(abs(first / second - 1.0)) if second != 0 else math.inf


def assess(case, result):
    """(status, diagnostics) of a finished compression; status ``ok`` or why it is not a modulus."""
    a = case.constants.axis
    last = case.samples[-1]
    H = np.asarray(last["H"])
    Ff, Fm = float(last["force_fixed"]), float(last["force_moving"])
    E, E_sec = result["young_modulus"], result["young_modulus_secant"]
    axial = abs(H[a, a])
    diag = {
        "force_fixed": Ff, "force_moving": Fm,
        "face_tilt": float(max(abs(H[a, b]) for b in range(3) if b != a) / axial) if axial > 0 else math.inf,
        "plate_mismatch": abs(Ff - Fm) / (0.5 * abs(Ff + Fm)) if Ff + Fm != 0 else math.inf,
        "slope_drift": _slope_drift(case),
        "secant_mismatch": abs(E_sec / E - 1.0) if np.isfinite(E) and E != 0 else math.inf,
    }
    if not (np.isfinite(E) and E > 0 and Ff > 0 and Fm > 0):
        return "lost_contact", diag
    if diag["face_tilt"] > FACE_TILT_MAX:
        return "rotated", diag
    if diag["plate_mismatch"] > PLATE_MISMATCH_MAX or diag["slope_drift"] > SLOPE_DRIFT_MAX:
        return "dynamic", diag
    return "ok", diag


def realisation_packing(deck, plan, case):
    """The compact packing of ``case`` (its realisation's seed, flat faces normal to its loading axis),
    shared by every case of that realisation loaded along the same axis; None for the ordered
    lattice. DeckError when the packing cannot be built (box too small, no jamming)."""
    if case.kind != "compact":
        return None
    dom = case_deck(deck, plan, case)["domain"]
    try:
        return compact_packing(dom["box"], dom["radius"], dom["dispersity"], dom["seed"], AXES.index(case.axis))
    except ValueError as err:
        raise DeckError(f"no compact packing for domain.box = {list(dom['box'])}, domain.radius = "
                        f"{dom['radius']}, domain.dispersity = {dom['dispersity']}, domain.seed = "
                        f"{dom['seed']}, loading axis {case.axis}: {err}") from None


def case_name(case):
    """File-name stem of a case (its series and ParaView folder), e.g.
    ``compact-r3-hankinson-q25-x-xi30``."""
    return (f"{case.kind}-r{case.realisation}-{case.law}-q{case.ratio:g}-{case.axis}-xi{case.tilt_deg:g}"
            .replace("/", "_"))


def run_case(comm, deck, plan, case, packing=None, outputs=None):
    """Compress ``case`` on the single-rank communicator ``comm``; a JSON-ready record.

    The plate speed makes the loading last ``plan.transits`` axial wave transits; a dynamic result
    is rerun ``SLOWER`` times slower, at most ``RETRIES`` times. Record keys: the case's fields,
    ``seed``, ``E`` (quasi-static slope [Pa]) and ``E_secant`` [Pa] as measured whatever the status,
    ``status``, the diagnostics of ``assess``, ``attempts``, ``steps``, ``n_elements``, ``n_bonds``,
    ``plate_speed`` [m/s], ``transits`` (of the last attempt), ``seconds`` (wall).
    ``packing``: the realisation's compact packing (``realisation_packing``), so it is built once.
    ``outputs(case, name, sim)``: a context manager giving (sinks, operations) of the attempt (series
    sinks fed every sample, writers run with the sampler; e.g. the driver's series files and ParaView
    writer); a retry rewrites them.
    """
    t0 = time.perf_counter()
    rec = asdict(case)
    rec["seed"] = plan.base_seed + case.realisation if case.kind != "ordered" else None
    transits = plan.transits
    try:
        for attempt in range(1, RETRIES + 2):
            probe = build_case(comm, case_deck(deck, plan, case), packing=packing)   # length, transit time
            slow = transit_factor(probe.deck, case)
            speed = probe.deck["loading"]["strain"] * probe.constants.length / (
                transits * slow * probe.constants.transit_time)
            run = with_plate_speed(probe, speed)
            if plan.steps is not None:
                run = replace(run, n_steps=min(run.n_steps, int(plan.steps)))
            every = run.deck["output"]["series_every"] or max(1, run.n_steps // 200)
            with (outputs(case, case_name(case), run.sim) if outputs else contextlib.nullcontext(((), ()))) as (
                    sinks, ops):
                sampler = SeriesSampler(run, every, sinks)
                sampler(run.sim)
                for op in ops:
                    op(run.sim)      # the initial state
                run.sim.run(run.n_steps, operations=[sampler, *ops])
            result = measure(run)
            status, diag = assess(run, result)
            rec.update(E=result["young_modulus"], E_secant=result["young_modulus_secant"], status=status,
                       attempts=attempt, steps=run.n_steps, n_elements=run.constants.n_elements,
                       n_bonds=run.constants.n_bonds, plate_speed=speed, transits=transits, **diag)
            if status != "dynamic":
                break
            transits *= SLOWER
    except DeckError as err:
        rec.update(E=math.nan, E_secant=math.nan, status="bad_input", message=str(err))
    except InstabilityError as err:
        rec.update(E=math.nan, E_secant=math.nan, status="unstable", message=str(err))
    rec["seconds"] = time.perf_counter() - t0
    return rec


def lattice_moduli(deck):
    """Beam theory of the ordered lattice of ``deck``'s bonds (docs/physics.md section 6): the domain
    moduli ``E_L, E_R, E_T = (pi/4) E_k r_k^2`` and the LR shear modulus
    ``G_LR = (3 pi/16) x y / (x + y)``, ``x, y = E_L r_L^4, E_R r_R^4`` [Pa] (the elements turn freely:
    the two bond families bend in series; ``calibration.lattice_shear_modulus``). The face-bonded
    lattice has Poisson ratios 0. Exact for the infinite lattice (Euler-Bernoulli bonds)."""
    E, r = as_lrt(deck["bonds"]["young"]), as_lrt(deck["bonds"]["radius_ratio"])
    out = {f"E_{k}": lattice_young(e, q) for k, e, q in zip("LRT", E, r)}
    out["G_LR"] = lattice_shear_modulus(E, r, "LR")
    return out


def orthotropic(E0, E90, K, xi_deg):
    """Off-axis modulus of an orthotropic solid under uniaxial stress at ``xi_deg`` from L in the LR
    plane [Pa]: ``1/E = cos^4/E0 + sin^4/E90 + K sin^2 cos^2`` with ``K = 1/G_LR - 2 nu_LR/E_L``
    [1/Pa] (the rotation of the compliance tensor: exact for any orthotropic linear elastic solid)."""
    s, c = math.sin(math.radians(xi_deg)), math.cos(math.radians(xi_deg))
    return 1.0 / (c**4 / E0 + s**4 / E90 + K * s * s * c * c)


def transit_factor(deck, case):
    """How many times longer than the axial wave transit of ``CompressionCase.transit_time`` (the
    stiffest bond chains closest to the load) the slowest wave of an off-axis ordered lattice takes:
    ``sqrt(E_chain / min(E(xi), G_LR))`` from ``lattice_moduli`` (a tilted lattice shears as it shortens,
    through its soft bending mode); 1 for a load along a grid axis and for compact domains (their
    shear coupling is weaker, and a dynamic case is rerun slower, ``SLOWER``)."""
    if case.kind != "ordered" or case.tilt_deg % 90.0 == 0.0:
        return 1.0
    m = lattice_moduli(deck)
    s, c = abs(math.sin(math.radians(case.tilt_deg))), abs(math.cos(math.radians(case.tilt_deg)))
    chain = m["E_L"] if c >= s else m["E_R"]
    slowest = min(orthotropic(m["E_L"], m["E_R"], 1.0 / m["G_LR"], case.tilt_deg), m["G_LR"])
    return math.sqrt(max(1.0, chain / slowest))


def case_id(rec):
    """The identity of a case (or of its record): kind, realisation, law, ratio, axis, tilt."""
    return (rec["kind"], int(rec["realisation"]), rec["law"], float(rec["ratio"]), rec["axis"],
            float(rec["tilt_deg"]))


def run_study(comm, case_comm, deck, plan, progress=None, packings=None, finished=None, on_record=None,
              outputs=None):
    """Run the plan over the ranks of ``comm`` (each case on ``case_comm``); every record on rank 0
    (sorted by case), None elsewhere. ``progress(done, total, record)`` is called on rank 0 for its
    own cases; ``packings`` maps (kind, realisation, axis) to packings this rank built already.
    ``finished`` maps ``case_id`` to the records of a previous run of the same plan (a restart):
    those cases are not run again. ``on_record(record)`` is called on the running rank after each
    case it runs (e.g. to append it to this rank's record file). ``outputs``: see ``run_case``."""
    finished = finished or {}
    groups = plan_cases(plan)
    mine = assign(groups, comm.size, plan)[comm.rank]
    total = sum(len(groups[g]) for g in mine)
    records, done = [], 0
    packings = dict(packings or {})
    for g in mine:
        for case in groups[g]:
            key = (case.kind, case.realisation, case.axis)
            if case_id(asdict(case)) in finished:
                records.append(dict(finished[case_id(asdict(case))]))
                done += 1
                continue
            if key not in packings:
                try:
                    packings[key] = realisation_packing(deck, plan, case)
                except DeckError as err:
                    packings[key] = err
            if isinstance(packings[key], DeckError):
                rec = dict(asdict(case), seed=plan.base_seed + case.realisation, E=math.nan, E_secant=math.nan,
                           status="bad_input", message=str(packings[key]), seconds=0.0)
            else:
                rec = run_case(case_comm, deck, plan, case, packings[key], outputs=outputs)
            rec["rank"] = comm.rank
            records.append(rec)
            if on_record is not None:
                on_record(rec)
            done += 1
            if progress is not None and comm.is_root:
                progress(done, total, rec)
        done_with = (groups[g][0].kind, groups[g][0].realisation)   # a group holds one realisation
        packings = {k: v for k, v in packings.items() if k[:2] != done_with}
    comm.wait_for_all()        # a rank done early sleeps here, not in the gather's busy poll
    gathered = comm.gather(records)
    if not comm.is_root:
        return None
    out = [r for part in gathered for r in part]
    return sorted(out, key=_case_key)


def _case_key(rec):
    return (KINDS.index(rec["kind"]) if rec["kind"] in KINDS else 99, rec["kind"], ALL_LAWS.index(rec["law"]),
            rec["ratio"], rec["tilt_deg"], rec["axis"], rec["realisation"])


def _stats(values):
    """(mean, std) of the finite values (sample std, ddof = 1; 0 for one value; None for none)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if len(v) == 0:
        return None, None
    return float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0


def hankinson(E0, E90, xi_deg):
    """Hankinson's off-axis modulus ``E0 E90 / (E0 sin^2 xi + E90 cos^2 xi)`` [Pa]."""
    s, c = math.sin(math.radians(xi_deg)), math.cos(math.radians(xi_deg))
    return E0 * E90 / (E0 * s * s + E90 * c * c)


def offaxis_fit_K(E0, E90, points):
    """``K = 1/G_LR - 2 nu_LR/E_L`` [1/Pa] of the orthotropic solid through the measured ``E0``, ``E90``
    that fits the measured ``points`` [(xi_deg, E)] best: least squares of ``1/E`` (``orthotropic``
    is linear in K: ``1/E - cos^4/E0 - sin^4/E90 = K sin^2 cos^2``); None without inner points."""
    w = [(math.sin(math.radians(x)) * math.cos(math.radians(x))) ** 2 for x, _ in points]
    if not points or max(w) < 1e-12:
        return None
    y = [1.0 / E - math.cos(math.radians(x)) ** 4 / E0 - math.sin(math.radians(x)) ** 4 / E90 for x, E in points]
    return sum(a * b for a, b in zip(w, y)) / sum(a * a for a in w)


def summarise(records, plan, deck=None):
    """The study's tables from the case records: ``data[kind][law]`` ratio rows and
    ``data["off_axis"][kind][law]`` xi rows (see the driver's docstring for the keys).

    Off-axis rows: ``E_hankinson`` from the measured E(0), E(90); ``E_orthotropic_fit``: the
    orthotropic solid through the measured E(0), E(90) whose K fits the inner angles best
    (``offaxis_fit_K``: one parameter for all inner angles, so the residuals say how orthotropic the
    domain is); ``E_orthotropic_lattice`` (ordered, when ``deck`` is given): the infinite lattice's
    orthotropic curve from beam theory (``lattice_moduli``: no measured input)."""
    index = {(r["kind"], r["law"], r["ratio"], r["axis"], r["tilt_deg"], r["realisation"]): r for r in records}

    def E(kind, law, q, axis, tilt, k):
        r = index.get((kind, law, q, axis, tilt, k))
        return r["E"] if r is not None and r["status"] == "ok" else None

    data = {"off_axis": {}}
    for kind in plan.kinds:
        data[kind] = {}
        n = plan.runs(kind)
        for law in plan.laws:
            rows = []
            for q in plan.ratios:
                per = [[E(kind, law, q, a, 0.0, k) for a in AXES] for k in range(n)]
                ok = [p for p in per if None not in p]
                row = {"bond_LR": q, "bond_LT": q * plan.E_R / plan.E_T}
                row["LR_mean"], row["LR_std"] = _stats([p[0] / p[1] for p in ok])
                row["LT_mean"], row["LT_std"] = _stats([p[0] / p[2] for p in ok])
                for name, col in zip("LRT", range(3)):
                    row[f"E_{name}_mean"], row[f"E_{name}_std"] = _stats([p[col] for p in per])
                row["n_realisations"], row["n_failed"] = n, n - len(ok)
                rows.append(row)
            data[kind][law] = rows
        if plan.xis():
            data["off_axis"][kind] = {}
            for law in plan.laws:
                rows = []
                for xi in plan.xis():
                    values = [E(kind, law, plan.offaxis_ratio, "x", xi, k) for k in range(n)]
                    mean, std = _stats(values)
                    rows.append({"xi_deg": xi, "E_mean": mean, "E_std": std, "E_hankinson": None,
                                 "n_realisations": n, "n_failed": sum(v is None for v in values),
                                 "statuses": sorted({index[(kind, law, plan.offaxis_ratio, "x", xi, k)]["status"]
                                                     for k in range(n)})})
                E0, E90 = rows[0]["E_mean"], rows[-1]["E_mean"]
                inner = [(r["xi_deg"], r["E_mean"]) for r in rows[1:-1] if r["E_mean"] is not None]
                theory = None
                if deck is not None and kind == "ordered":
                    raw = copy.deepcopy(raw_deck(deck))
                    raw["bonds"]["young"] = [plan.offaxis_ratio * plan.E_R, plan.E_R, plan.E_T]
                    theory = lattice_moduli(raw)
                for row in rows:
                    row["E_orthotropic_fit"] = row["E_orthotropic_lattice"] = None
                    if E0 is not None and E90 is not None:
                        row["E_hankinson"] = hankinson(E0, E90, row["xi_deg"])
                        K = offaxis_fit_K(E0, E90, inner)
                        if K is not None:
                            row["E_orthotropic_fit"] = orthotropic(E0, E90, K, row["xi_deg"])
                    if theory is not None:
                        row["E_orthotropic_lattice"] = orthotropic(theory["E_L"], theory["E_R"], 1.0 / theory["G_LR"],
                                                                   row["xi_deg"])
                data["off_axis"][kind][law] = rows
    return data


def _fmt(mean, std, width=8):
    if mean is None:
        return f"{'failed':>{2 * width + 3}}"
    return f"{mean:{width}.3f} +- {std:<{width}.3f}"


def format_table(data, plan):
    """The printed table (text)."""
    lines = []
    for kind in plan.kinds:
        runs = plan.runs(kind)
        lines.append(f"\n{kind} domains ({runs} realisation{'s' if runs > 1 else ''}): domain anisotropy "
                     f"E_L^D/E_R^D and E_L^D/E_T^D against the bond ratios")
        lines.append(f"{'law':<10} {'E_L/E_R':>7} {'E_L/E_T':>7}   {'E_L^D/E_R^D':^22} {'E_L^D/E_T^D':^22} failed")
        for law in plan.laws:
            for row in data[kind][law]:
                lines.append(f"{law:<10} {row['bond_LR']:7.3g} {row['bond_LT']:7.3g}   "
                             f"{_fmt(row['LR_mean'], row['LR_std'])}  {_fmt(row['LT_mean'], row['LT_std'])}  "
                             f"{row['n_failed']}/{row['n_realisations']}")
    for kind, laws in data["off_axis"].items():
        lines.append(f"\n{kind} domains, off-axis (compression along x, frame tilted by xi, "
                     f"E_L/E_R = {plan.offaxis_ratio:g}): E(xi) [MPa] and Hankinson's prediction from E(0), E(90)")
        lines.append(f"{'law':<10} {'xi':>4}   {'E(xi)':^22} {'Hankinson':>9}  status")
        for law, rows in laws.items():
            for row in rows:
                mean = None if row["E_mean"] is None else row["E_mean"] / 1e6
                std = None if row["E_std"] is None else row["E_std"] / 1e6
                h = "n/a" if row["E_hankinson"] is None else f"{row['E_hankinson'] / 1e6:.3f}"
                lines.append(f"{law:<10} {row['xi_deg']:4.0f}   {_fmt(mean, std)} {h:>9}  "
                             f"{','.join(row['statuses'])}")
    return "\n".join(lines)
