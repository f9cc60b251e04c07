"""Calibration of compact (random) domains by measurement. docs/physics.md sections 4 and 6.

A compact domain has no closed-form relation between its bonds and its moduli (W calibrates it by
hand). This module finds the bond moduli ``E_L^mu, E_R^mu, E_T^mu`` and bond radius ratios that give
the domain its target moduli ``E_L^D, E_R^D, E_T^D`` and ``G^D``, by Newton iterations on measured
moduli:

1. Start: the ordered lattice's closed-form bonds (``calibration.calibrate``) times the deck's
   ``compact.start_factors`` (1 = the closed form; the tests start far from it on purpose).
2. Measure: per realisation (packing seed ``domain.seed + k``, ``k < compact.realisations``) the
   compressions along L, R, T (``pardem.protocols.compression``, each on the packing with flat faces
   normal to its axis, loaded over ``compact.transits`` axial wave transits, quasi-static slope) and
   simple shear in ``compact.shear_plane`` (``compact_shear``; every plane with ``all``). The
   measured modulus of a target is the mean over the realisations.
3. Sensitivities, measured in the same runs: a domain of linear-elastic bonds loaded by imposed
   displacements stores the energy ``U = sum_b U_b`` at equilibrium; by the envelope theorem (the
   free elements minimise U), ``d ln M / d ln k_b = U_b / U`` for every stiffness constant ``k_b``
   the energy is linear in. A bond's axial energy scales with ``E_b r_b^2``, its bending and twist
   energies with ``E_b r_b^4``; a bond's modulus responds to the axis values by
   ``w_bj = d ln E_b / d ln E_j`` of its anisotropy law (``law_weights``; 0 or 1 for TOR; the same
   for the radius triple). Hence the sensitivity matrix, in logarithms::

       J[i, E_j] = sum_b w_bj U_b / U,    J[i, r_j] = sum_b w^r_bj (2 U_ax,b + 4 U_bt,b) / U

   (``bond_energy_shares``, from the bonds' end state; rows of the mean over realisations are
   weighted by each realisation's modulus). It is exact to first order for the bonds' part of the
   response; the plates' contacts and the loading rate make it approximate, which only slows the
   convergence. Every row of ``J[:, E]`` sums to 1 (scaling every bond modulus scales every
   domain modulus: a check of the measurement, reported).
4. Update: ``ln p += J^-1 (ln target - ln measured)`` (a Newton step on the logarithms, with a
   slight Levenberg-Marquardt damping), each component bounded by ``ln compact.max_step``; the
   bound halves after an iteration that did not lower the largest error (a trust region).
   Reachability and uniqueness: the moduli respond to the bond radius almost alike (axial energy
   ~ r^2, bending ~ r^4, and both carry every modulus), so ``G^D / E^D`` moves only weakly with the
   radius (Poisson ratios 0.05-0.1, ``G ~ E / 2``; G_LT / E_L measured 0.462 and 0.461 at r = 0.4 and
   0.7 with equal bonds; the smallest singular value of J is about 0.03 against 6 for the largest
   on the test domain). A shear target far from what the bond network gives cannot be met: the
   iteration stalls and reports it (exit code 6; the singular values are in the history). A target
   within reach is met by a family of bond sets (moduli and radii traded along that weak
   direction); the iteration returns the one it reaches from its start.
5. Stop when every target is met within ``compact.tolerance`` (2 %), or after
   ``compact.max_iterations`` measurements (not converged). The unknowns are the three bond moduli
   and one common factor of the bond radii with one shear plane (4 targets, 4 unknowns), or the
   three radii with ``all`` planes (6 and 6).

Task farm: realisation k runs on rank ``k mod n_ranks`` of the job, alone (``Communicator.split_self``),
each rank building its packings once for every iteration; the per-realisation results are
gathered in realisation order and every rank computes the same update, so the iterations are the
same for any number of ranks (each realisation's run is bitwise the same on any rank).

The simple shear of a compact domain (``compact_shear``): the packing has flat faces normal to the
gradient axis b (its loading axis); the elements whose centres lie within ``DRIVE_DEPTH`` mean radii
of the extreme centres along a and along b (the faces that carry the shear traction) are driven
through the affine simple shear ``u_a = gamma (X_b - c_b)`` with the continuum's rotation
``gamma / 2`` (``pardem.protocols.shear.ShearDrive``); the free interior finds its state through the
dynamics. Stress: the force of the bonds crossing the mid-plane normal to b over the box section
(``pardem.protocols.shear.ShearSampler``), strain from the least-squares gradient of the free
elements; the modulus is the slope over the constant-rate phase.

Pure protocol code: MPI only through ``Communicator``, no files (the driver writes the history).
"""
import copy
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from pardem.config import DeckError, check_deck
from pardem.domains import compact
from pardem.errors import InstabilityError
from pardem.engine.state import FLAG_NEAR_PLATE
from pardem.physics import anisotropy
from pardem.physics.beam import compute_bonds
from pardem.protocols import calibration as calib
from pardem.protocols.compression import SeriesSampler, build_case, measure, with_plate_speed
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.protocols.shear import ShearDrive, ShearSampler, shear_deck, shear_history

AXES = calib.AXES                  # L, R, T -> x, y, z (the frame is untilted)
DRIVE_DEPTH = 2.5                  # driven layers of the compact shear test: centres within 2.5 mean
                                   # radii of the extreme centres (the first layer of a flat face and
                                   # about 1.25 diameters of a periodic cut face)
SHEAR_ESTIMATE = 0.4               # G ~ 0.4 E of the same realisation (isotropic, nu = 0.25): only
                                   # sets the shear test's loading time
LAW_STEP = 1e-4                    # relative step of the law weights' central difference
MIN_FIT_SAMPLES = 3
LM_DAMPING = 1e-3                  # Levenberg-Marquardt damping of the Newton step / largest singular value
SHRINK = 0.5                       # the step bound shrinks by this when an iteration made no progress


@dataclass(frozen=True)
class CompactPlan:
    """What the compact calibration measures (from the checked calibrate deck).

    targets : names (``young_L``, ``young_R``, ``young_T``, ``shear_<plane>``...); values [Pa];
    realisations, seeds : their count and packing seeds; planes : shear planes; per_radius : one
    radius unknown per direction (``all`` planes) or one common factor; strain, shear_strain [-];
    transits : loading time in wave transits; tolerance [-]; max_iterations; max_step [-].
    """
    targets: tuple
    values: tuple
    seeds: tuple
    planes: tuple
    per_radius: bool
    strain: float
    shear_strain: float
    transits: float
    tolerance: float
    max_iterations: int
    max_step: float

    @property
    def unknowns(self):
        return ("young_L", "young_R", "young_T") + (("radius_L", "radius_R", "radius_T") if self.per_radius
                                                    else ("radius_scale",))


def make_plan(deck):
    """The ``CompactPlan`` of a checked calibrate deck whose ``domain.kind`` is compact."""
    c = deck["compact"]
    targets = calib.Targets.from_deck(deck)
    planes = tuple(calib.SHEAR_PLANES) if c["shear_plane"] == "all" else (c["shear_plane"],)
    names = ("young_L", "young_R", "young_T") + tuple(f"shear_{p}" for p in planes)
    values = tuple(targets.young()) + (targets.shear,) * len(planes)
    base = deck["domain"]["seed"]
    return CompactPlan(targets=names, values=values, seeds=tuple(base + k for k in range(c["realisations"])),
                       planes=planes, per_radius=len(planes) == 3, strain=c["strain"],
                       shear_strain=c["shear_strain"], transits=c["transits"], tolerance=c["tolerance"],
                       max_iterations=c["max_iterations"], max_step=c["max_step"])


def start_bonds(deck):
    """(young (L, R, T) [Pa], radius_ratio (L, R, T)) of the first iteration: the closed form of
    ``bonds.relations`` times ``compact.start_factors`` (moduli) and ``compact.start_radius_factor``."""
    cal = calib.calibrate(calib.Targets.from_deck(deck), deck["bonds"]["relations"])
    f = deck["compact"]["start_factors"]
    s = deck["compact"]["start_radius_factor"]
    return (tuple(float(e * k) for e, k in zip(cal.young, f)), tuple(float(r * s) for r in cal.radius_ratio))


def compress_raw(deck, young, radius_ratio, seed=None):
    """The raw compress deck of the compact domain of ``deck`` with these bonds (elastic).

    Element density ``rho_D / 0.64`` (``compact.TARGET_FRACTION``: the packings end at 0.63-0.64, so the
    represented density is within 1.5 %; it sets only the dynamics, not the moduli)."""
    dom, bd = deck["domain"], deck["bonds"]
    return {"domain": {"kind": "compact", "box": list(dom["box"]), "radius": dom["radius"],
                       "density": deck["targets"]["density"] / compact.TARGET_FRACTION,
                       "dispersity": dom["dispersity"], "bond_gap": dom["bond_gap"],
                       "seed": int(dom["seed"] if seed is None else seed), "tilt_deg": 0.0},
            "bonds": {"young": [float(x) for x in young], "radius_ratio": [float(x) for x in radius_ratio],
                      "law": bd["law"], "poisson": bd["poisson"], "damping": bd["damping"]}}


def law_weights(law, u, frame, values):
    """``w[b, j] = d ln v_b / d ln v_j`` [n, 3] of the law's value for bond directions ``u`` [n, 3]
    with respect to the axis values ``values`` (L, R, T) (central difference in ln v_j, step
    LAW_STEP; TOR's 0 or 1 to rounding). Every law is homogeneous of degree 1, so rows sum to 1."""
    v = np.asarray(values, dtype=np.float64)
    w = np.empty((len(u), 3))
    h = math.log1p(LAW_STEP)
    for j in range(3):
        up, down = v.copy(), v.copy()
        up[j] *= math.exp(h)
        down[j] *= math.exp(-h)
        w[:, j] = np.log(anisotropy.evaluate(law, u, frame, up) / anisotropy.evaluate(law, u, frame, down)) / (2 * h)
    return w


def _weights(sim, law, young, radius_ratio):
    """(w_E, w_r) [n_bonds, 3] of the bonds of ``sim`` at their creation directions."""
    e, b = sim.elements, sim.bonds
    d = e.x0[b.j] - e.x0[b.i]
    u = d / np.linalg.norm(d, axis=1)[:, None]
    frame = anisotropy.lrt_frame(0.0)
    return law_weights(law, u, frame, young), law_weights(law, u, frame, radius_ratio)


def bond_energy_shares(comm, sim, w_E, w_r):
    """``(U, s_E [3], s_r [3])``: the bonds' elastic energy U [J] in the current state (collective),
    ``s_E[j] = sum_b w_E[b, j] U_b / U`` and ``s_r[j] = sum_b w_r[b, j] (2 U_ax,b + 4 U_bt,b) / U``
    (module docstring), from the beam force loop (``physics.beam.compute_bonds``, undamped, on scratch
    force arrays) with scaled stiffness constants (the energy is linear in ka, kb, kt), bonds counted
    once over the ranks."""
    e, b = sim.elements, sim.bonds
    once = b.counted_once(e.n_owned).astype(np.float64)       # 0 for bonds another rank counts
    scratch = dataclasses.replace(e, f=np.zeros_like(e.f), t=np.zeros_like(e.t))

    def energy(ka, kb, kt):
        elastic = dataclasses.replace(b, ka=ka * once, kb=kb * once, kt=kt * once, damped=False, breakable=False,
                                      densify_p0=0.0)
        return compute_bonds(elastic, scratch)[0]
    zero = np.zeros(len(b.ka))
    local = np.zeros(7)
    local[0] = energy(b.ka, b.kb, b.kt)
    for j in range(3):
        local[1 + j] = energy(b.ka * w_E[:, j], zero, zero) + energy(zero, b.kb * w_E[:, j], b.kt * w_E[:, j])
        local[4 + j] = (2.0 * energy(b.ka * w_r[:, j], zero, zero)
                        + 4.0 * energy(zero, b.kb * w_r[:, j], b.kt * w_r[:, j]))
    g = comm.sum(local)
    U = float(g[0])
    if not U > 0.0:
        return U, [math.nan] * 3, [math.nan] * 3
    return U, [float(x / U) for x in g[1:4]], [float(x / U) for x in g[4:7]]


def compression_test(comm, raw, axis, packing, strain, transits, law, young, radius_ratio):
    """Compression of the compact domain ``raw`` along ``axis`` ("x", "y", "z") on ``packing`` (flat
    faces normal to it), loaded over ``transits`` axial wave transits (collective over ``comm``).
    Returns {"modulus" [Pa], "modulus_secant" [Pa], "poisson_ratios", "steps", "n_elements",
    "energy" [J], "share_E", "share_r"}."""
    raw = copy.deepcopy(raw)
    raw.setdefault("loading", {}).update(axis=axis, strain=strain)
    probe = build_case(comm, check_deck(COMPRESS_SCHEMA, raw), packing=packing)
    c = probe.constants
    case = with_plate_speed(probe, strain * c.length / (transits * c.transit_time))
    w_E, w_r = _weights(case.sim, law, young, radius_ratio)
    sampler = SeriesSampler(case, max(1, case.n_steps // 100))
    sampler(case.sim)
    case.sim.run(case.n_steps, operations=[sampler])
    result = measure(case)
    U, s_E, s_r = bond_energy_shares(comm, case.sim, w_E, w_r)
    return {"modulus": result["young_modulus"], "modulus_secant": result["young_modulus_secant"],
            "poisson_ratios": result["poisson_ratios"], "steps": case.n_steps,
            "n_elements": c.n_elements, "n_bonds": c.n_bonds,
            "solid_fraction": c.domain_facts.get("solid_fraction"), "energy": U, "share_E": s_E, "share_r": s_r}


def compact_shear(comm, raw, plane, packing, strain, transits, estimate, law, young, radius_ratio):
    """Simple shear of the compact domain ``raw`` in ``plane`` on ``packing`` (flat faces normal to the
    gradient axis b), up to the engineering strain ``strain`` over ``transits`` shear-wave transits
    along b at the speed ``sqrt(estimate / rho_D)`` (``estimate`` [Pa]); collective. Module docstring.
    Returns {"modulus" [Pa] (slope), "modulus_secant" [Pa], "gamma", "steps", "n_elements", "n_driven",
    "energy" [J], "share_E", "share_r"}."""
    a, b = calib.SHEAR_PLANES[plane]
    deck = shear_deck(check_deck(COMPRESS_SCHEMA, raw), plane)
    case = build_case(comm, deck, packing=packing, plates=False)
    sim = case.sim
    e = sim.elements
    R = case.constants.domain_facts["mean_radius"]
    w_E, w_r = _weights(sim, law, young, radius_ratio)
    n = e.n_owned
    lo = np.array([comm.min(float(e.x0[:n, d].min()) if n else math.inf) for d in range(3)])
    hi = np.array([comm.max(float(e.x0[:n, d].max()) if n else -math.inf) for d in range(3)])
    driven = np.zeros(e.n_total, dtype=bool)
    for d in (a, b):
        driven |= (e.x0[:, d] < lo[d] + DRIVE_DEPTH * R) | (e.x0[:, d] > hi[d] - DRIVE_DEPTH * R)
    e.inv_mass[driven] = 0.0
    e.inv_inertia[driven] = 0.0
    e.flags[:] &= ~FLAG_NEAR_PLATE
    e.flags[driven] |= FLAG_NEAR_PLATE              # left out of the strain fit
    box = np.asarray(deck["domain"]["box"], dtype=np.float64)
    c = 3 - a - b
    area = float(box[a] * box[c])
    centre_b = 0.5 * (lo[b] + hi[b])
    mass = float(comm.sum(float(e.mass[:n].sum())))
    transit = box[b] / math.sqrt(estimate / (mass / float(np.prod(box))))
    ramp = 2.0 * transit
    duration = transits * transit + 0.5 * ramp
    rate = strain / (duration - 0.5 * ramp)
    n_steps = max(1, math.ceil(duration / sim.dt - 1e-9))
    mover = ShearDrive(a, b, centre_b, rate, ramp, turn=0.5)
    sampler = ShearSampler(comm, a, b, centre_b, area, case.constants.origin, max(1, n_steps // 100))
    mover(sim)
    sampler(sim)
    sim.run(n_steps, operations=[mover, sampler])
    s = sampler.samples
    t = np.array([x["time"] for x in s])
    g = np.array([x["gamma"] for x in s])
    tau = np.array([x["stress"] for x in s])
    keep = t >= ramp
    slope = (float(np.polyfit(g[keep], tau[keep], 1)[0]) if keep.sum() >= MIN_FIT_SAMPLES and np.ptp(g[keep]) > 0
             else math.nan)
    U, s_E, s_r = bond_energy_shares(comm, sim, w_E, w_r)
    return {"modulus": slope, "modulus_secant": float(tau[-1] / g[-1]) if g[-1] != 0 else math.nan,
            "gamma": float(g[-1]), "gamma_imposed": float(shear_history(sim.time, rate, ramp)),
            "steps": n_steps, "n_elements": int(comm.sum(float(n))),
            "n_driven": int(comm.sum(float(driven[:n].sum()))), "energy": U, "share_E": s_E, "share_r": s_r}


class PackingCache:
    """The packings of this rank's realisations, built once (seed, flat axis) -> CompactPacking."""

    def __init__(self, deck):
        self.dom = deck["domain"]
        self._p = {}

    def get(self, seed, axis):
        key = (int(seed), "xyz".index(axis))
        if key not in self._p:
            d = self.dom
            try:
                self._p[key] = compact.compact_packing(d["box"], d["radius"], d["dispersity"], key[0], key[1])
            except ValueError as err:
                raise DeckError(f"no compact packing for domain.box = {list(d['box'])}, domain.radius = "
                                f"{d['radius']}, domain.dispersity = {d['dispersity']}, seed {key[0]}, flat "
                                f"axis {axis}: {err}; expected edges of at least {compact.RELIABLE_EDGE:g} "
                                f"radii (or a wider dispersity)") from None
        return self._p[key]


def measure_realisation(comm, deck, plan, seed, young, radius_ratio, packings):
    """Every test of one realisation (packing seed ``seed``) with these bonds, on ``comm`` (usually a
    single rank). Returns {target name: run record} in ``plan.targets`` order."""
    raw = compress_raw(deck, young, radius_ratio, seed)
    law = deck["bonds"]["law"]
    out = {}
    for k, axis in AXES.items():
        out[f"young_{k}"] = compression_test(comm, raw, axis, packings.get(seed, axis), plan.strain, plan.transits,
                                             law, young, radius_ratio)
    E_mean = float(np.mean([out[f"young_{k}"]["modulus"] for k in "LRT"]))
    estimate = SHEAR_ESTIMATE * E_mean if math.isfinite(E_mean) and E_mean > 0 else plan.values[-1]
    for p in plan.planes:
        b = "xyz"[calib.SHEAR_PLANES[p][1]]
        out[f"shear_{p}"] = compact_shear(comm, raw, p, packings.get(seed, b), plan.shear_strain, plan.transits,
                                          estimate, law, young, radius_ratio)
    return out


def farm_measure(comm, deck, plan, young, radius_ratio, packings):
    """Measure every realisation, spread over the ranks of ``comm`` (realisation k on rank k mod size,
    alone); every rank gets the list of per-realisation results in realisation order (each with the
    ``rank`` that ran it)."""
    mine = {}
    own = comm.split_self()
    for k, seed in enumerate(plan.seeds):
        if k % comm.size == comm.rank:
            try:
                mine[k] = measure_realisation(own, deck, plan, seed, young, radius_ratio, packings)
            except DeckError as err:            # reported after the gather, on every rank alike
                mine[k] = {"error": str(err)}
            except InstabilityError as err:
                mine[k] = {"unstable": f"(realisation {k}, seed {seed}) {err}"}
            mine[k]["rank"] = comm.rank
    comm.wait_for_all()        # a rank done early sleeps here, not in the allgather's busy poll
    gathered = comm.allgather(mine)
    merged = {}
    for part in gathered:
        merged.update(part)
    return [merged[k] for k in range(len(plan.seeds))]


def _raise_failures(results):
    """Raise, on every rank alike, the first realisation's failure: DeckError (no packing) or
    InstabilityError."""
    for r in results:
        if "error" in r:
            raise DeckError(r["error"])
        if "unstable" in r:
            raise InstabilityError(r["unstable"])


def combine(plan, per_realisation):
    """(measured mean [n_targets] [Pa], sensitivity matrix J [n_targets, n_unknowns], per-target
    spreads) of the per-realisation records (module docstring, step 3)."""
    n_t = len(plan.targets)
    M = np.array([[r[name]["modulus"] for name in plan.targets] for r in per_realisation])   # [n_real, n_t]
    mean = M.mean(axis=0)
    J = np.zeros((n_t, len(plan.unknowns)))
    for i, name in enumerate(plan.targets):
        rows = []
        for r, rec in enumerate(per_realisation):
            sE, sr = np.array(rec[name]["share_E"]), np.array(rec[name]["share_r"])
            rows.append(np.concatenate([sE, sr if plan.per_radius else [sr.sum()]]))
        w = M[:, i] / M[:, i].sum()
        J[i] = w @ np.array(rows)
    std = M.std(axis=0, ddof=1) if len(M) > 1 else np.zeros(n_t)
    return mean, J, std


def newton_step(plan, J, measured, bound):
    """The damped Newton step on ``ln`` of the unknowns (module docstring, step 4): the
    Levenberg-Marquardt solution of ``J s = ln target - ln measured`` with damping ``mu = LM_DAMPING
    sigma_max`` (a direction the moduli hardly respond to, e.g. the radius's weak lever on G / E, is
    not followed blindly), each component then bounded by ``bound`` (the whole step scaled)."""
    residual = np.log(np.asarray(plan.values)) - np.log(measured)
    u, sv, vt = np.linalg.svd(J, full_matrices=False)
    mu = LM_DAMPING * sv[0]
    step = vt.T @ ((sv / (sv * sv + mu * mu)) * (u.T @ residual))
    big = float(np.max(np.abs(step)))
    if big > bound:
        step *= bound / big
    return step


def apply_step(plan, young, radius_ratio, step):
    """New (young, radius_ratio) triples after the step on their logarithms."""
    young = tuple(float(e * math.exp(s)) for e, s in zip(young, step[:3]))
    if plan.per_radius:
        radius_ratio = tuple(float(r * math.exp(s)) for r, s in zip(radius_ratio, step[3:6]))
    else:
        radius_ratio = tuple(float(r * math.exp(step[3])) for r in radius_ratio)
    return young, radius_ratio


def calibrate_compact(comm, deck, say=lambda text: None, on_iteration=None):
    """The iterative calibration of the compact domain of the checked calibrate ``deck`` (collective).

    Returns a dict: ``converged``, ``iterations``, ``history`` (per iteration: bonds, measured means
    and per-realisation moduli, relative errors, sensitivity matrix, step), ``bonds`` (the last
    measured set: the calibrated one when converged), ``measured``, ``relative_error``, ``plan``.
    ``on_iteration(entry)`` after each iteration (every rank).
    """
    plan = make_plan(deck)
    young, radius = start_bonds(deck)
    packings = PackingCache(deck)
    history = []
    converged = False
    bound, previous_worst = math.log(plan.max_step), None
    for it in range(plan.max_iterations):
        results = farm_measure(comm, deck, plan, young, radius, packings)
        _raise_failures(results)
        mean, J, std = combine(plan, results)
        rel = mean / np.asarray(plan.values) - 1.0
        finite = bool(np.all(np.isfinite(mean)) and np.all(mean > 0) and np.all(np.isfinite(J)))
        entry = {"iteration": it, "young": list(young), "radius_ratio": list(radius),
                 "measured": dict(zip(plan.targets, mean.tolist())),
                 "spread": dict(zip(plan.targets, std.tolist())),
                 "relative_error": dict(zip(plan.targets, rel.tolist())),
                 "per_realisation": [{name: r[name]["modulus"] for name in plan.targets} for r in results],
                 "ranks": [r["rank"] for r in results],
                 "sensitivity": J.tolist(), "sensitivity_E_row_sums": J[:, :3].sum(axis=1).tolist(),
                 "singular_values": (np.linalg.svd(J, compute_uv=False).tolist() if np.all(np.isfinite(J))
                                     else None),
                 "runs": [{name: {k: v for k, v in r[name].items() if k not in ("share_E", "share_r")}
                           for name in plan.targets} for r in results]}
        converged = finite and bool(np.all(np.abs(rel) <= plan.tolerance))
        say(f"iteration {it}: E^mu (L, R, T) = {', '.join(f'{x:.5g}' for x in young)} Pa, r = "
            f"{', '.join(f'{x:.4g}' for x in radius)}; measured "
            + ", ".join(f"{n} {m:.5g} Pa ({100 * e:+.2f} %)" for n, m, e in zip(plan.targets, mean, rel)))
        if not finite:
            entry["step"] = None
            history.append(entry)
            if on_iteration:
                on_iteration(entry)
            break
        if converged:
            entry["step"] = None
        else:
            worst = float(np.max(np.abs(rel)))
            if previous_worst is not None and worst >= previous_worst:
                bound *= SHRINK                       # no progress: a smaller trust region
            previous_worst = worst
            step = comm.bcast(newton_step(plan, J, mean, bound))
            entry["step_bound"] = bound
            entry["step"] = step.tolist()
            entry["next_young"], entry["next_radius_ratio"] = (list(x) for x in apply_step(plan, young, radius, step))
        history.append(entry)
        if on_iteration:
            on_iteration(entry)
        if converged:
            break
        young, radius = (tuple(entry["next_young"]), tuple(entry["next_radius_ratio"]))
    last = history[-1]
    return {"converged": converged, "iterations": len(history), "history": history,
            "bonds": {"young": last["young"], "radius_ratio": last["radius_ratio"], "law": deck["bonds"]["law"]},
            "measured": last["measured"], "relative_error": last["relative_error"],
            "targets": dict(zip(plan.targets, plan.values)), "unknowns": list(plan.unknowns),
            "seeds": list(plan.seeds), "tolerance": plan.tolerance, "max_iterations": plan.max_iterations,
            "shear_planes": list(plan.planes), "transits": plan.transits, "strain": plan.strain,
            "shear_strain": plan.shear_strain}


def measure_bonds(comm, deck, young, radius_ratio, seeds=None):
    """An independent measurement of bonds ``(young, radius_ratio)`` on the deck's compact domain:
    the mean modulus per target over the realisations ``seeds`` (default the plan's), with fresh
    packings (collective; the same farm). Returns {target: mean [Pa]}, per-realisation list."""
    plan = make_plan(deck)
    if seeds is not None:
        plan = CompactPlan(**{**plan.__dict__, "seeds": tuple(seeds)})
    results = farm_measure(comm, deck, plan, tuple(young), tuple(radius_ratio), PackingCache(deck))
    _raise_failures(results)
    mean, _, _ = combine(plan, results)
    return dict(zip(plan.targets, mean.tolist())), [{n: r[n]["modulus"] for n in plan.targets} for r in results]
