"""Isotropic preparation of a granular packing and its elastic moduli. docs/physics.md sections 8, 11, 12.

Protocol (driver ``python -m pardem.drivers.isotropic``; steps 1 to 3 are the relaxation stage other
protocols share: ``pardem.protocols.stages.prepare``, the gas ``pardem.domains.gas``, the measures
``pardem.engine.packing``):

1. **Gas.** ``n`` spheres of the deck's radii (``sample.radii`` with ``sample.fractions``, assigned
   in a seeded random order) at random non-overlapping centres (random sequential addition with a
   cell grid, ``numpy.random.default_rng(seed)``) in a cubic periodic cell at the solid fraction
   ``sample.gas_solid_fraction``. Built on rank 0 and broadcast, so a seed gives the same gas on any
   number of ranks.
2. **Compression (frictionless Hertz, servo).** The cell shrinks under the servo
   ``deps/dt = gain (p - p0)`` with ``gain = preparation.servo_rate / p0`` (so ``servo_rate`` [1/s]
   is the strain rate at a pressure error of 100 %), capped at ``preparation.max_rate`` [1/s] and
   its gain at ``1 / (2 S dt)`` (``ServoStiffness``: without it the loop overshoots and diverges
   once the packing is stiff, e.g. 2,000 glass spheres at 10 kPa), with
   the kinetic energy removed by FIRE (``preparation.relaxation = "fire"``, ``pardem.engine.relaxation``)
   or by the global viscous damping ``-C m v``, ``-C I w`` (``"viscous"``, ``preparation.damping`` =
   C [1/s]). FIRE adapts its time step: up to ``preparation.fire_max_dt`` times the run's step and
   to half the Verlet limit of the current contacts (their stiffness grows with the overlap, so at
   low pressure the Rayleigh step is several times too cautious); the run's step is restored
   afterwards. At 2,000 spheres and 100 kPa FIRE reaches equilibrium in 303k steps (350k at the
   fixed step), where viscous damping is still at a force ratio of 2e-2 after 400k. The run goes
   on, servo still active, until static equilibrium at p0. (Relaxing at fixed volume instead does
   not work near jamming: the servo-compressed packing unjams, p falls to zero.)
3. **Static equilibrium** (checked every ``preparation.check_every`` steps), all three at once:

   * kinetic energy: ``E_k / N < kinetic_tolerance * p0 * V_mean`` with ``V_mean`` the mean sphere
     volume. ``E_k / (N p0 V_mean) = rho <v^2> / (2 p0)`` is the dynamic pressure of the velocity
     fluctuations against p0 (the square of an inertial number); default 1e-9: at 100 kPa glass
     that is a speed of 3e-4 m/s, an oscillation amplitude of about 2e-3 of the mean overlap.
   * force balance: ``mean_k |F_k| / mean_c |f_c| < force_tolerance`` (default 1e-4), the mean
     unbalanced contact force on the elements (viscous drag excluded: it is removed from the force
     of the step using the half-step velocity that produced it) over the mean contact force;
   * pressure: ``|p - p0| / p0 < pressure_tolerance`` (default 1e-3).

   Then the servo stops (the cell is fixed) and the state is measured: p, Z = 2 N_c / N, the solid
   fraction (overlap lenses removed), Z without rattlers and the normal force distribution.
   Pressures of ``--pressures`` are taken from low to high, each continuing the previous packing.
4. **Rattlers** (on rank 0 from the gathered contact network of force-carrying contacts,
   ``delta > 0``): an element with fewer than ``d + 1 = 4`` such contacts is a rattler; it and its
   contacts are removed and the count is repeated until no element is removed.
   ``Z_no_rattlers = 2 N_c' / N'`` over the remaining elements and contacts.
5. **Moduli.** Friction ``material.friction`` is switched on (contacts undamped, the tangential
   history starts at zero, so the static state is unchanged) and the velocities and the last
   forces are zeroed. A small affine strain increment is applied to the cell at a constant rate
   over ``moduli.ramp_steps`` steps (default 2000) through its diagonal rate, so positions map
   affinely and the contact laws see the affine relative motion ``-g d dt`` for the tangential
   increment: isotropic compression ``diag(-e, -e, -e)``, then a volume-preserving shear
   ``diag(+e, -e, 0)``. The stress after the ramp's FIRST step is the **affine** response (no
   relaxation; the zeroed forces make that step's drift purely affine): the tangent at zero strain
   to O(e / ramp_steps) (with ``ramp_steps = 1`` the secant over e). After the ramp the cell stays
   fixed and the packing relaxes (damping) until the kinetic and force criteria hold again: the
   **relaxed** response. Conventions (pressure compression positive, stress tension positive)::

       K  = (p1 - p0) / (-(V1 - V0) / V0)
       mu = ((s_xx - s_yy)_1 - (s_xx - s_yy)_0) / (2 (eps_xx - eps_yy)),   eps_aa = L_a1 / L_a0 - 1

   Why a ramp: applied in ONE step the strain makes the packing ring; every contact is loaded and
   unloaded repeatedly, and the Mindlin spring's unloading rescale shrinks the tangential forces on
   each unloading half-cycle without giving them back, so the relaxed mu comes out low in
   proportion to e (200 glass spheres at 1 MPa: 3.9 % below the static linear response in one step,
   0.25 % after a 2000-step ramp, the rest being the sliding of one contact in 630; K: -5.9e-4 and
   +2.2e-5). 2000 steps are about 23 shear-wave transits of that cell (``L / c_s`` = 86 steps), 6
   of the 10,000-sphere deck's; from 2000 to 10000 steps the relaxed moduli change by < 3e-4.

   For an isotropic packing ``mu`` is docs/physics.md's ``1/2 dsigma_12 / deps_12`` (the shear in the
   axes turned by 45 deg; the cell supports diagonal rates only). The shear starts from the relaxed
   state of the isotropic increment.
   ``moduli.strain = "auto"`` takes ``e = 0.01 <delta / d>`` (mean over the contacts of overlap over
   centre distance): the normal force of a mean contact changes by about 1.5 %, so the Hertz law is
   linear to about 0.3 %, and the tangential force reaches ``kt e d / fn = 1.5 (kt / kn) e d / delta
   ~ 0.013 fn``, far below ``mu fn`` (no sliding, except in contacts with almost no overlap); the
   stress increments are then about 1e-2 of p at every pressure, well above the equilibrium's
   residual drift. A fixed number (1e-6 to 1e-5) may be given instead.

   **Static moduli** (``moduli.static = true``, the default): before the increments, the static
   linear response of the prepared contact network (``pardem.protocols.moduli_check``: stiffness
   matrix, one sparse solve on rank 0) gives the protocol's secants at the same strain e without
   any dynamics: ``K_static``, ``mu_static`` in the rows, ``details[k]["static"]`` (with the
   tangents at zero strain, sliding fractions, EMT in 3D) and ``details[k]["moduli"]["static"]``
   (static beside relaxed and ``relaxed / static - 1``). The two agree within the Hertz
   nonlinearity at strain e (second order: the static secant is a trapezoid), the relaxation
   residual and the sliding of the weakest contacts (tests/test_linear_response.py).
6. Before the next pressure the friction is switched off again (history cleared) and the servo
   resumes at the new p0.

**2D mode** (``[domain] dimension = 2``, ``pardem.engine.plane``): the same protocol with spheres
(full mass and inertia, 3D Hertz-Mindlin contacts) whose centres lie in the plane z = 0, moving in
x, y and turning about z, in a square cell periodic in x and y. The gas is a random sequential
addition of disks at the area fraction ``sample.gas_solid_fraction``; stresses are per unit area
of the plane divided by the mean diameter ``t`` (the cell's thickness, ``PeriodicCell``), in Pa;
the pressure is ``p = -(s_xx + s_yy) / 2``; the servo drives x and y; the solid fraction is the
disk area over the cell area with the overlap lenses (circular segments) removed
(``pardem.physics.structure.solid_fraction``); rattlers have fewer than ``d + 1 = 3`` contacts;
the bulk increment is ``diag(-e, -e, 0)`` and ``K = (p1 - p0) / (-(A1 - A0) / A0)`` (2D bulk
modulus), the shear increment and ``mu`` as in 3D; the static moduli are those of the 2D modes
(``moduli_check.evaluate_2d``; 100 disks at 1 MPa: relaxed / static - 1 = 3e-6 for K, -2.5e-4 for mu
with the ramp, -4.0 % for mu in one step).

The contact law is Hertz-Mindlin (``pardem.physics.hertz_mindlin``); all loops over elements and
contacts per step run in the engine's Numba kernels; the checks are numpy over arrays every
``check_every`` steps.
"""
import time

import numpy as np

from pardem.config import DeckError, Field, Schema, auto_or, boolean, choice, number, number_list, positive
from pardem.engine.packing import network
from pardem.physics import hertz_mindlin
from pardem.physics.timestep import rayleigh_time_step
from pardem.protocols import deck_checks as dc
from pardem.protocols import moduli_check
from pardem.protocols.granular_output import CHECKPOINT_SECTION, DOMAIN_SECTION, domain_checks, run_section
from pardem.protocols import output_deck
from pardem.protocols.stages import SweepRun, contact_params, dimension, prepare, relax, young_modulus

ROW_KEYS = ("p0", "p", "Z", "Z_no_rattlers", "solid_fraction", "K_affine", "K_relaxed", "mu_affine",
            "mu_relaxed", "K_static", "mu_static")
MODULI_KEYS = ("K_affine", "K_relaxed", "mu_affine", "mu_relaxed")
# the default ramp of an increment: about 23 shear-wave transits of the 200-sphere test cell at 1 MPa
# (L / c_s = 86 steps), 6 of the 10,000-sphere deck's; measured there (200 spheres, 1 MPa) the relaxed
# K and mu change by 2e-6 and 1.1e-4 from 2000 to 10000 steps, where one step loses 3.9 % of mu
DEFAULT_RAMP_STEPS = 2000
# moduli.static = "auto" computes the static moduli up to this many grains: 200 spheres take 0.5 s,
# a 500-grain network of Z = 12 (perturbed FCC, denser than a random packing's 6) 34 s and one of
# 2048 grains more than 600 s (measured on 2 cores shared with other jobs, so slow by up to 8x)
STATIC_AUTO_MAX = 1000


def sample_checks(deck):
    """Cross-field checks of the deck's sample (run by ``config.check_deck``): one fraction per
    radius, representable masses, a memory estimate within the machine's (of the replicated packing
    when the deck has ``replicate.copies``)."""
    s = deck["sample"]
    k = deck["replicate"]["copies"] if "replicate" in deck else [1, 1]
    if len(s["fractions"]) != len(s["radii"]):
        raise DeckError(f"sample.fractions has {len(s['fractions'])} entries: expected one per radius "
                        f"({len(s['radii'])}) of sample.radii")
    r_min, r_max = min(s["radii"]), max(s["radii"])
    mean_volume = sum(f * 4.0 / 3.0 * np.pi * dc.cube(r) for f, r in zip(s["fractions"], s["radii"])) \
        / sum(s["fractions"])
    dc.granular_checks(float(s["n"]) * k[0] * k[1], s["density"], r_min, r_max, mean_volume,
                       "sample.n, replicate.copies, sample.radii" if "replicate" in deck else "sample.n, sample.radii")


def pressure_checks(deck):
    """Every pressure of the deck (``preparation.pressures`` or ``preparation.pressure``,
    ``loading.confining_pressures``) at most ``deck_checks.MAX_PRESSURE_FRACTION`` of the grains'
    Young modulus."""
    E = young_modulus(deck["material"])
    for section, key in (("preparation", "pressures"), ("preparation", "pressure"), ("loading", "confining_pressures")):
        value = deck.get(section, {}).get(key)
        if value is not None:
            dc.check_pressures(value if isinstance(value, (list, tuple)) else [value], E, f"{section}.{key}",
                               "material.shear_modulus, material.poisson")


def run_checks(deck):
    """The time step (``run.dt_fraction`` of the Rayleigh step of the smallest sphere) is a normal
    double; the largest run the step caps allow is at most ``MAX_STEPS``; the servo's largest rate
    cannot move the cell faster than the grains' wave speed; the drag removes less than the whole
    velocity per step."""
    s, mat, pr, mo = deck["sample"], deck["material"], deck["preparation"], deck["moduli"]
    r_min = min(s["radii"])
    dt = deck["run"]["dt_fraction"] * rayleigh_time_step(r_min, s["density"], mat["shear_modulus"],
                                                         mat["poisson"])
    dc.check_normal(dt, "the time step", "s", "run.dt_fraction, material.shear_modulus, sample.density, "
                                              "sample.radii")
    per_pressure = pr["max_steps"] + (2 * (mo["max_relax_steps"] + mo["ramp_steps"]) if mo["enabled"] else 0)
    dc.check_steps(len(pr["pressures"]) * per_pressure, "preparation.pressures, preparation.max_steps, "
                   "moduli.max_relax_steps, moduli.ramp_steps", "the step caps allow a run that")
    if mo["strain"] != "auto":
        # the first step of the ramp gives the affine moduli: its strain must be resolvable
        per_step = float(mo["strain"]) / mo["ramp_steps"]
        if per_step < dc.MIN_STRAIN:
            raise DeckError(f"moduli.ramp_steps = {mo['ramp_steps']}: the strain per step moduli.strain / "
                            f"ramp_steps = {per_step:.3g} is below {dc.MIN_STRAIN:g} (not resolvable in double "
                            f"precision); expected ramp_steps in [1, {int(float(mo['strain']) / dc.MIN_STRAIN)}]")
    mean_volume = 4.0 / 3.0 * np.pi * dc.cube(r_min)
    edge = (s["n"] * mean_volume / dc.DENSEST_FRACTION) ** (1.0 / 3.0)
    if deck["domain"]["dimension"] == 2:   # disks at the densest (hexagonal) area fraction
        edge = np.sqrt(s["n"] * np.pi * r_min * r_min / (np.pi / np.sqrt(12.0)))
    E = young_modulus(mat)
    dc.check_rate(pr["max_rate"], edge, np.sqrt(E / s["density"]), "preparation.max_rate",
                  "material.shear_modulus, sample.density")
    dc.check_drag(pr["damping"], dt, "preparation.damping")


SCHEMA = Schema({
    "domain": DOMAIN_SECTION,
    "sample": {
        "n": Field(10000, number(lo=8, lo_open=False, integer=True), "number of spheres"),
        "radii": Field([0.105e-3, 0.095e-3], number_list(positive()), "sphere radii [m] (one per species)"),
        "fractions": Field([0.5, 0.5], number_list(positive()),
                           "number fractions of the species (normalised; same length as radii)"),
        "density": Field(2500.0, positive(), "grain density [kg/m^3]"),
        "seed": Field(1, number(lo=0, lo_open=False, integer=True), "seed of the gas (centres and radii order)"),
        "gas_solid_fraction": Field(0.25, number(0.0, 0.33), "solid fraction of the initial gas"),
    },
    "material": {
        "shear_modulus": Field(30e9, dc.modulus(), "grain shear modulus G [Pa]"),
        "poisson": Field(0.2, number(-1.0, 0.5), "grain Poisson ratio"),
        "friction": Field(0.3, number(lo=0.0, lo_open=False),
                          "contact friction when measuring the moduli (preparation is frictionless)"),
        "restitution": Field(1.0, number(0.0, 1.0, hi_open=False),
                             "normal restitution of the contacts during preparation (moduli: undamped)"),
    },
    "preparation": {
        "pressures": Field([1e5, 1e6, 1e7, 1e8], number_list(positive()),
                           "target pressures p0 [Pa], run from low to high"),
        "servo_rate": Field(4000.0, positive(),
                            "servo strain rate at a pressure error of 100 % [1/s] (gain = servo_rate / p0); "
                            "the gain is capped at 1 / (2 S dt) with S = -dp/de the packing's affine "
                            "stiffness (PeriodicCell), so the loop stays stable at any p0 and step"),
        "max_rate": Field(1000.0, positive(), "largest strain rate of the servo [1/s] (the gas compression rate)"),
        "relaxation": Field("fire", choice("viscous", "fire"),
                            "how the kinetic energy is removed during preparation: fire (FIRE "
                            "quench, pardem.engine.relaxation; no drag) or viscous (global drag C)"),
        "fire_max_dt": Field(10.0, number(1.0, 100.0, hi_open=False),
                             "FIRE's largest time step, as a multiple of the run's (run.dt_fraction); "
                             "the step also stays below half the Verlet limit of the current contacts"),
        "damping": Field(1e5, positive(), "global viscous damping C [1/s] (drag -C m v, -C I w): "
                                          "preparation with relaxation = viscous, and the relaxed moduli"),
        "check_every": Field(200, number(lo=1, lo_open=False, integer=True),
                             "steps between equilibrium checks"),
        "max_steps": Field(400000, number(lo=1, lo_open=False, integer=True),
                           "largest number of steps per pressure (compression and relaxation)"),
    },
    "equilibrium": {
        "kinetic_tolerance": Field(1e-9, dc.tolerance(), "E_k / (N p0 V_mean) below this"),
        "force_tolerance": Field(1e-4, dc.tolerance(), "mean unbalanced force / mean contact force below this"),
        "pressure_tolerance": Field(1e-3, dc.tolerance(), "|p - p0| / p0 below this"),
    },
    "moduli": {
        "enabled": Field(True, boolean, "measure the moduli at each pressure"),
        "strain": Field("auto", auto_or(number(dc.MIN_STRAIN, 1e-2, lo_open=False)),
                        "affine strain increment e, or auto = 0.01 <delta / d> over the contacts"),
        "max_relax_steps": Field(200000, number(lo=1, lo_open=False, integer=True),
                                 "largest number of steps of each relaxation after an increment"),
        "ramp_steps": Field(DEFAULT_RAMP_STEPS, number(lo=1, lo_open=False, hi=1e7, hi_open=False, integer=True),
                            "steps over which each strain increment is applied at a constant rate (1 = in one "
                            "step, which biases the relaxed mu low by a few %); the first step gives the affine "
                            "(tangent) moduli"),
        "static": Field("auto", auto_or(boolean),
                        "also compute the static linear-response moduli of each prepared packing "
                        "(pardem.protocols.moduli_check: five sparse LU factorisations on rank 0, whose "
                        f"cost grows fast with n); auto = when sample.n <= {STATIC_AUTO_MAX}"),
    },
    "run": run_section("Rayleigh critical step",
                       "displacement budget between list rebuilds; auto = 0.2 x the smallest radius"),
    "checkpoint": CHECKPOINT_SECTION,
    "output": output_deck.output_section(plot_figures="isotropic.png and force_distribution.png"),
}, checks=(domain_checks, sample_checks, run_checks, pressure_checks))

# the series: one row per equilibrium check (every preparation.check_every steps) of every stage
STAGES = ("prepare", "K", "mu")      # the series' stage codes 0, 1, 2
SERIES_COLUMNS = ("step", "time", "pressure_index", "stage", "p0", "pressure", "solid_fraction",
                  "coordination", "kinetic", "unbalanced", "unbalanced_max", "dt", "cell_rate")
SERIES_UNITS = ("1", "s", "1", "1", "Pa", "Pa", "1", "1", "1", "1", "1", "s", "1/s")
SERIES_INT = ("step", "pressure_index", "stage")
SERIES_DESCRIPTION = (
    "pardem isotropic series: one row per equilibrium check (every preparation.check_every steps) of "
    "the preparation at the target pressure p0 (stage 0) and of the relaxations after the bulk (1) "
    "and shear (2) strain increments; pressure p (compression positive; 2D: -(s_xx + s_yy) / 2, "
    "stress per unit area over the mean diameter), solid fraction (sphere volume over cell volume, "
    "2D: disk area over cell area; overlaps not removed), coordination 2 N_c / N, kinetic = E_k / (N p0 "
    "V_mean), unbalanced (mean and max unbalanced force over the mean contact force), the time step "
    "(FIRE adapts it) and the cell's strain rate; one dataset per column with its 'units'")


def check_sample(deck):
    """Cross-field checks of a checked deck (raises ``DeckError``)."""
    s = deck["sample"]
    if len(s["fractions"]) != len(s["radii"]):
        raise DeckError(f"sample.fractions has {len(s['fractions'])} entries: expected one per radius "
                        f"({len(s['radii'])})")


def increment(sim, sign, e, tol, check_every, max_steps, progress=None, label="", run=None, resume=False,
              ramp_steps=1):
    """The affine strain increment ``diag(sign) * e`` of the cell applied at a constant rate over
    ``ramp_steps`` steps (velocities and the last forces zeroed first), then relaxation at fixed
    cell (kinetic and force criteria). Collective.

    The stress after the FIRST step is the affine response to that step's strain (the forces
    were zeroed, so the grains' drift is purely the cell's affine map): with ``ramp_steps = 1`` the
    secant over e, otherwise the tangent at zero strain to O(e / ramp_steps). The per-step factor
    is ``(1 + sign e)^(1 / ramp_steps)``, so that the edges change by exactly ``1 + sign e``.

    Returns a dict: ``s0``, ``affine``, ``relaxed`` stresses [3, 3] [Pa] (tension positive),
    ``L0``, ``L_affine``, ``L1`` cell edges [3] [m] before, after the first step and after the
    ramp, ``converged``, ``steps`` (of the relaxation after the ramp), ``unbalanced``.
    ``run``: the ``SweepRun`` (keeps the increment in its state; its operations, e.g. the
    checkpoints, also run during the ramp); ``resume``: continue the increment of its state (the
    rest of its ramp, then the relaxation).
    """
    ramp_steps = int(ramp_steps)
    if ramp_steps < 1:
        raise ValueError(f"increment: ramp_steps = {ramp_steps}, expected an integer >= 1")
    ops = run.operations if run is not None else []
    if resume:
        inc = run.state["increment"]
        s0, L0 = np.asarray(inc["s0"]), np.asarray(inc["L0"])
        end = int(inc.get("ramp_end", run.state["start"]))
        if inc.get("affine") is None:
            # stopped by a signal right after the first step: the checkpoint holds that step's
            # contact sums, so its stress is the affine one
            inc["affine"], inc["L_affine"] = sim.global_stress().tolist(), sim.cell.length.tolist()
        s_aff = np.asarray(inc["affine"])
        L_aff = np.asarray(inc.get("L_affine", inc.get("L1")))
        if sim.step_count < end:       # checkpointed during the ramp: finish it at the same rate
            sim.cell.rate = np.asarray(inc["rate"], dtype=float)
            sim.run(end - sim.step_count, ops)
            sim.cell.rate = np.zeros(3)
            inc["L1"] = sim.cell.length.tolist()
        L1 = np.asarray(inc["L1"])
        start = int(run.state["start"])
    else:
        n = sim.elements.n_total
        sim.elements.v[:n] = 0.0
        sim.elements.w[:n] = 0.0
        # the first half kick would drift the grains by the residual forces' f dt^2 / 2m; of the
        # order of the affine motion of one step of a long ramp, so the forces are zeroed (the
        # second half kick recomputes them: the relaxation is unchanged but for that half kick)
        sim.elements.f[:n] = 0.0
        sim.elements.t[:n] = 0.0
        s0 = sim.global_stress()
        L0 = sim.cell.length.copy()
        sign = np.asarray(sign, dtype=float)
        rate = (np.power(1.0 + sign * e, 1.0 / ramp_steps) - 1.0) / sim.dt
        start = sim.step_count + ramp_steps
        inc = {"s0": s0.tolist(), "affine": None, "L0": L0.tolist(), "L_affine": None, "L1": None,
               "rate": rate.tolist(), "ramp_end": start}
        if run is not None:
            # in the state before the first step: a checkpoint (or a stop) during the ramp resumes it
            run.state["increment"] = inc
            run.state["start"] = start
        sim.cell.rate = rate
        sim.run(1)
        s_aff = sim.global_stress()
        L_aff = sim.cell.length.copy()
        inc["affine"], inc["L_affine"] = s_aff.tolist(), L_aff.tolist()
        if ramp_steps > 1:
            sim.run(ramp_steps - 1, ops)
        sim.cell.rate = np.zeros(3)
        L1 = sim.cell.length.copy()
        inc["L1"] = L1.tolist()
    b, ok, steps = relax(sim, tol, check_every, max_steps, progress=progress, label=label, start=start,
                         run=run)
    return {"s0": s0, "affine": s_aff, "relaxed": b["stress"], "L0": L0, "L_affine": L_aff, "L1": L1,
            "converged": ok, "steps": steps, "unbalanced": b["unbalanced"]}


def bulk_modulus(s0, s1, L0, L1, dim=3):
    """``K = (p1 - p0) / (-(V1 - V0) / V0)`` [Pa], p = -trace / 3; 2D (``dim = 2``): p = -(s_xx +
    s_yy) / 2 and the area ``L_x L_y`` instead of V."""
    if dim == 2:
        ds = np.asarray(s1) - np.asarray(s0)
        area = (L1[0] * L1[1]) / (L0[0] * L0[1])
        return float(-(ds[0, 0] + ds[1, 1]) / 2.0 / -(area - 1.0))
    return float(-np.trace(s1 - s0) / 3.0 / -(np.prod(L1) / np.prod(L0) - 1.0))


def shear_modulus(s0, s1, L0, L1):
    """``mu = D(s_xx - s_yy) / (2 (eps_xx - eps_yy))`` [Pa], eps_aa = L1_a / L0_a - 1."""
    eps = np.asarray(L1) / np.asarray(L0) - 1.0
    return float(((s1[0, 0] - s1[1, 1]) - (s0[0, 0] - s0[1, 1])) / (2.0 * (eps[0] - eps[1])))


ISOTROPIC, SHEAR = (-1.0, -1.0, -1.0), (1.0, -1.0, 0.0)
ISOTROPIC_2D = (-1.0, -1.0, 0.0)     # the in-plane bulk increment of a 2D cell


def measuring_contacts(sim, material):
    """Switch the contacts to the moduli's law: friction ``material.friction``, undamped, history
    cleared (the frictionless static state is unchanged); servo off, cell fixed."""
    sim.contacts.params = hertz_mindlin.Params(**contact_params(material, material["friction"], 1.0))
    sim.contacts.history[:] = 0.0
    sim.cell.servo = None
    sim.cell.rate = np.zeros(3)


def moduli(sim, deck, strain, progress=None, run=None, resume=False):
    """Bulk and shear moduli of the static packing of ``sim`` (cell fixed), affine and relaxed [Pa].

    See the module docstring (step 5). Returns a dict with ``K_affine, K_relaxed, mu_affine,
    mu_relaxed``, the ``strain`` used, ``ramp_steps`` and the relaxations' convergence. Collective. ``run``,
    ``resume``: as for ``prepare`` (the moduli so far are in the run's state).
    """
    tol = deck["equilibrium"]
    every, most = deck["preparation"]["check_every"], deck["moduli"]["max_relax_steps"]
    ramp = int(deck["moduli"].get("ramp_steps", 1))
    if resume:
        mat = deck["material"]   # the measuring law; the history and the cell are the checkpoint's
        sim.contacts.params = hertz_mindlin.Params(**contact_params(mat, mat["friction"], 1.0))
        out = run.state["moduli"]
    else:
        measuring_contacts(sim, deck["material"])
        out = {"strain": strain, "ramp_steps": ramp}
        if run is not None:
            run.state["moduli"] = out
    dim = sim.cell.dimension
    bulk = ISOTROPIC_2D if dim == 2 else ISOTROPIC
    for name, sign, fn in (("K", bulk, lambda *a: bulk_modulus(*a, dim=dim)), ("mu", SHEAR, shear_modulus)):
        if f"{name}_affine" in out:
            continue      # measured before the checkpoint this run resumed from
        if run is not None:
            run.state["stage"] = name
        r = increment(sim, sign, strain, tol, every, most, progress, f"relaxing ({name})", run=run,
                      resume=resume, ramp_steps=ramp)
        resume = False
        out[f"{name}_affine"] = fn(r["s0"], r["affine"], r["L0"], r["L_affine"])
        out[f"{name}_relaxed"] = fn(r["s0"], r["relaxed"], r["L0"], r["L1"])
        out[f"{name}_relax_converged"] = r["converged"]
        out[f"{name}_relax_steps"] = r["steps"]
        out[f"{name}_relax_unbalanced"] = r["unbalanced"]
    return out


def sweep(comm, deck, pressures, progress=None, case=None, run=None):
    """Prepare at each pressure (ascending, continuing the packing), measure, and the moduli.

    Returns ``(rows, details, case)``: ``rows`` one dict per pressure with ``ROW_KEYS`` (SI),
    ``details`` per pressure (equilibrium measures, rattlers, force distribution, strain...).
    ``progress``: a ``pardem.io.progress.Progress``. ``run``: a ``SweepRun`` (the driver's
    checkpoints, series and stop); with a checkpoint's state and ``case`` restored from it, the
    sweep continues where that checkpoint was written. The wall times of ``details``
    (``seconds``, ``moduli_seconds``) count this process only.
    """
    run = SweepRun() if run is None else run
    st = run.state
    rows, details = st["rows"], st["details"]
    pressures = sorted(float(p) for p in pressures)
    while st["index"] < len(pressures):
        p0 = pressures[st["index"]]
        resume, run.resuming = run.resuming, False
        t0 = time.perf_counter()
        if st["stage"] == "prepare":
            if progress is not None:
                progress.say(f"{'continuing' if resume else 'preparing'} at p0 = {p0:.6g} Pa")
            case, info = prepare(comm, deck, p0, case, progress, run=run, resume=resume)
            resume = False
            sim = case.sim
            sim.elements.v[:] = 0.0
            sim.elements.w[:] = 0.0
            net = network(sim)
            b = info["balance"]
            row = {"p0": p0, "p": net["p"], "Z": net["Z"], "Z_no_rattlers": net["Z_no_rattlers"],
                   "solid_fraction": net["solid_fraction"], "K_affine": None, "K_relaxed": None,
                   "mu_affine": None, "mu_relaxed": None, "K_static": None, "mu_static": None}
            det = {"p0": p0, "converged": info["converged"], "steps": info["steps"],
                   "kinetic": b["kinetic"], "unbalanced": b["unbalanced"],
                   "unbalanced_max": b["unbalanced_max"], "pressure_error": net["p"] / p0 - 1.0,
                   "rattlers": net["rattlers"], "n_contacts": net["n_contacts"],
                   "mean_overlap_ratio": net["mean_overlap_ratio"],
                   "force_distribution": net["force_distribution"], "cell_length": sim.cell.length.tolist()}
            mo = deck["moduli"]
            if mo["enabled"] and static_wanted(deck):
                # the frictionless equilibrium before any increment: the state the linear response
                # linearises (no tangential force); collective, nothing of the simulation changes
                t1 = time.perf_counter()
                static = moduli_check.static_moduli(sim, deck["material"], strain_of(deck, det))
                if static is None:     # no backbone: K_static, mu_static stay None
                    det["static"] = None
                    if progress is not None:
                        progress.say("  static moduli: none (no grain has two contacts: not jammed)")
                else:
                    det["static"] = moduli_check.compact(static)
                    row["K_static"], row["mu_static"] = det["static"]["K_static"], det["static"]["mu_static"]
                    if progress is not None:   # (its wall time is in details' seconds, not in the record:
                        # the records are compared bit for bit between rank counts)
                        progress.say(f"  static moduli (linear response, {time.perf_counter() - t1:.1f} s): "
                                     f"K = {row['K_static']:.6g}, mu = {row['mu_static']:.6g} Pa")
            st["row"], st["det"], st["moduli"], st["increment"] = row, det, None, None
            st["stage"] = "K" if mo["enabled"] else "measured"
            if progress is not None:
                progress.say(f"  equilibrium at p0 = {p0:.6g} Pa ({'converged' if info['converged'] else 'NOT converged'}"
                             f", {info['steps']} steps, {time.perf_counter() - t0:.1f} s): p = {net['p']:.6g} Pa, "
                             f"Z = {net['Z']:.4f}, Z without rattlers = {net['Z_no_rattlers']:.4f} "
                             f"({net['rattlers']} rattlers), solid fraction {net['solid_fraction']:.5f}")
        row, det, sim = st["row"], st["det"], case.sim
        if st["stage"] in ("K", "mu"):
            t1 = time.perf_counter()
            e = strain_of(deck, det)
            if resume and progress is not None:
                progress.say(f"continuing the moduli at p0 = {p0:.6g} Pa ({st['stage']})")
            mod = moduli(sim, deck, e, progress, run=run, resume=resume)
            for k in MODULI_KEYS:
                row[k] = mod[k]
            if det.get("static") is not None:
                mod["static"] = moduli_check.compare(det["static"], mod)
            det["moduli"] = mod
            det["moduli_seconds"] = time.perf_counter() - t1
            if progress is not None:
                progress.say(f"  moduli (e = {e:.3g}, ramp of {mod['ramp_steps']} steps): K = {mod['K_affine']:.6g} "
                             f"affine, {mod['K_relaxed']:.6g} relaxed; mu = {mod['mu_affine']:.6g} affine, "
                             f"{mod['mu_relaxed']:.6g} relaxed [Pa]"
                             + (f"; static K = {row['K_static']:.6g}, mu = {row['mu_static']:.6g} "
                                f"(relaxed / static - 1: {mod['static']['K_difference']:.2e}, "
                                f"{mod['static']['mu_difference']:.2e})" if "static" in mod else ""))
        det["seconds"] = time.perf_counter() - t0
        rows.append(row)
        details.append(det)
        st.update(index=st["index"] + 1, stage="prepare", row=None, det=None, moduli=None, increment=None)
    st["done"] = True
    return rows, details, case


def static_wanted(deck):
    """``moduli.static`` resolved: true, false, or "auto" = ``sample.n <= STATIC_AUTO_MAX``."""
    v = deck["moduli"].get("static", False)
    return deck["sample"]["n"] <= STATIC_AUTO_MAX if v == "auto" else bool(v)


def strain_of(deck, det):
    """The increment's strain e of a pressure: ``moduli.strain``, "auto" = 0.01 <delta / d> of
    its prepared packing (``det["mean_overlap_ratio"]``)."""
    e = deck["moduli"]["strain"]
    return 0.01 * det["mean_overlap_ratio"] if e == "auto" else float(e)


def stress_convention(sim):
    """The stress convention of the run, for the summary: 3D Love-Weber over the cell volume; 2D
    per unit area of the plane over the thickness (the mean diameter) [m]."""
    cell = sim.cell
    if cell.dimension == 2:
        return {"stress": "Love-Weber sum_c d_i f_j / (L_x L_y t), tension positive [Pa]: per unit area "
                          "of the plane divided by t, the mean diameter",
                "thickness": cell.thickness, "pressure": "-(s_xx + s_yy) / 2",
                "solid_fraction": "disk area minus the lens areas over L_x L_y"}
    return {"stress": "Love-Weber sum_c d_i f_j / V, tension positive [Pa]", "pressure": "-trace / 3",
            "solid_fraction": "sphere volume minus the lens volumes over V"}


def criteria_text(deck):
    t = deck["equilibrium"]
    return {"kinetic": f"E_k / (N p0 V_mean) < {t['kinetic_tolerance']:g} (V_mean: mean sphere volume)",
            "force": f"mean_k |F_k| / mean_c |f_c| < {t['force_tolerance']:g} (unbalanced contact force "
                     "on the elements over the mean contact force, drag excluded)",
            "pressure": f"|p - p0| / p0 < {t['pressure_tolerance']:g} (preparation only)",
            "rattlers": f"elements with fewer than {dimension(deck) + 1} force-carrying contacts, removed "
                        "iteratively"}
