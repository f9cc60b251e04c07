"""Triaxial test of a cemented granular packing in a periodic cell (docs/physics.md sections 8, 11, 12).

Protocol (all on ``pardem.engine.granular`` cases, any number of ranks):

1. **Preparation** (minimal; ``prepare``): ``N = per_edge^3`` spheres, radii uniform in
   ``R (1 +- dispersity)``, on a jittered cubic lattice at solid fraction ``gas_fraction`` with random
   velocities (``numpy.random.default_rng(seed)``: the same sample on any number of ranks), are
   compressed isotropically by the cell's pressure servo ``deps/dt = gain (p - pc)`` (rate capped)
   with global viscous damping and the preparation's friction (default 0: a dense packing), until
   the pressure is within ``tolerance`` of ``pc`` and the kinetic energy below
   ``kinetic_ratio`` times the contacts' elastic energy, on ``checks`` consecutive checks.
2. **Cementation** (``cement``): the loading friction and the cement springs are switched on (the
   forces do not change: the cement starts unstressed), the damping is removed and every contact
   gets an intact cement with ``delta0`` its current overlap and a rupture energy drawn uniformly in
   ``threshold_mean +- threshold_half_width`` (``pardem.engine.cement``: a function of the seed and the gid
   pair, so 1 and N ranks agree).
3. **Triaxial loading** (``load``): the axial edge shortens at ``strain_rate`` (``dL/dt = -rate L``,
   the cell's diagonal rate; the loading stops when ``1 - L / L0`` reaches ``strain``), the two
   lateral edges are servo-controlled to hold their normal stress at ``-pc``
   (``PeriodicCell.triaxial_servo``), no global damping (the contacts' restitution dissipates).

Measures (``sample``; compression positive): axial strain ``eps_a = 1 - L_a / L_a0``, volumetric
strain ``eps_v = 1 - V / V0`` (contraction positive), axial and lateral stresses ``sigma_a = -s_aa``,
``sigma_l = -(s_bb + s_cc) / 2`` from the Love-Weber stress ``s`` (tension positive; contact and
cement forces), deviator ``q = sigma_a - sigma_l``, mean stress ``p``, the cement counts (intact,
fading) and the broken fraction ``1 - intact / N_cemented`` (each pair counted once, over all ranks),
the coordination ``Z = 2 N_c / N`` (pairs that interact, cement in tension included).
"""
import math

import numpy as np

from pardem.engine import cement as cementing
from pardem.engine import granular
from pardem.engine.system import (Cell, ContactModel, Decomposition, Integration, Particles, System,
                                  set_contact_params)
from pardem.physics.contact_laws import critical_time_step, law_params
from pardem.config import DeckError, Field, Schema, choice, number, positive
from pardem.protocols import deck_checks as dc
from pardem.engine.periodic_cell import PeriodicCell
from pardem.parallel.exact_sum import exact_sum
from pardem.protocols.granular_output import CHECKPOINT_SECTION, RowSampler, StepLimit, run_section
from pardem.protocols import output_deck

AXES = "xyz"


def sample_checks(deck):
    """Representable masses and a memory estimate within the machine's (``config.check_deck``)."""
    s = deck["sample"]
    R, d = s["radius"], s["dispersity"]
    n = float(s["per_edge"]) ** 3
    mean_volume = 4.0 / 3.0 * math.pi * dc.cube(R) * (1.0 + d * d)    # <r^3> of radii uniform in R (1 +- d)
    dc.granular_checks(n, s["density"], R * (1.0 - d), R * (1.0 + d), mean_volume, "sample.per_edge, sample.radius")


def pressure_checks(deck):
    """The confining pressure at most ``deck_checks.MAX_PRESSURE_FRACTION`` of the grains' Young
    modulus."""
    dc.check_pressures([deck["loading"]["confining_pressure"]], deck["contacts"]["young"],
                       "loading.confining_pressure", "contacts.young")


def run_checks(deck):
    """The time step (``time_step``: Rayleigh and cement steps of the smallest sphere) is a normal
    double; the loading (``loading_steps``' count: each step shortens the axial edge by the factor
    ``1 - rate dt``) takes at most ``MAX_STEPS`` steps; no servo or loading rate moves the cell
    faster than the grains' wave speed; the drag removes less than the whole velocity per step."""
    s, ld, pr = deck["sample"], deck["loading"], deck["preparation"]
    try:
        dt = time_step(deck)
    except (ValueError, ArithmeticError) as err:
        raise DeckError(f"contacts, cement and run.dt_fraction give no time step ({err})") from None
    keys = "run.dt_fraction, contacts.young, cement.normal_stiffness, sample.density, sample.radius"
    dc.check_normal(dt, "the time step", "s", keys)
    R, d = s["radius"], s["dispersity"]
    edge = (float(s["per_edge"]) ** 3 * 4.0 / 3.0 * math.pi * dc.cube(R * (1.0 - d)) / dc.DENSEST_FRACTION) \
        ** (1.0 / 3.0)
    c = math.sqrt(deck["contacts"]["young"] / s["density"])
    for key, rate in (("loading.strain_rate", ld["strain_rate"]), ("loading.max_rate", ld["max_rate"]),
                      ("preparation.max_rate", pr["max_rate"])):
        dc.check_rate(rate, edge, c, key, "contacts.young, sample.density")
    per_step = ld["strain_rate"] * dt      # < 1 here: the rate is below c / edge and dt below R / c
    steps = math.log1p(-ld["strain"]) / math.log1p(-per_step) if 0.0 < per_step < 1.0 else math.inf
    dc.check_steps(steps, f"loading.strain, loading.strain_rate and the time step ({keys})", "the loading")
    dc.check_drag(pr["viscous_damping"], dt, "preparation.viscous_damping")


SCHEMA = Schema({
    "sample": {
        "per_edge": Field(10, number(lo=3, lo_open=False, integer=True),
                          "spheres per edge of the initial lattice: N = per_edge^3"),
        "radius": Field(0.5e-3, positive(), "mean sphere radius R [m]"),
        "dispersity": Field(0.1, number(0.0, 0.3, lo_open=False), "radii uniform in R (1 +- dispersity)"),
        "density": Field(2500.0, positive(), "grain density [kg/m^3]"),
        "gas_fraction": Field(0.3, number(0.05, 0.45), "solid fraction of the initial gas"),
        "gas_speed": Field(0.1, number(lo=0.0, lo_open=False), "r.m.s. speed of the initial gas per axis [m/s]"),
        "seed": Field(1, number(lo=0, lo_open=False, integer=True),
                      "seed of radii, jitter and velocities (the same sample on any number of ranks)"),
    },
    "contacts": {
        "young": Field(70e9, dc.modulus(), "grains' Young modulus [Pa] (glass)"),
        "poisson": Field(0.3, number(-1.0, 0.5), "grains' Poisson ratio"),
        "friction": Field(0.3, number(lo=0.0, lo_open=False), "Coulomb friction of the loading"),
        "restitution": Field(0.5, number(0.0, 1.0, hi_open=False),
                             "normal restitution of the Hertz contacts (contact damping)"),
    },
    "cement": {
        "normal_stiffness": Field(2e5, positive(), "cement normal spring Sn [N/m]"),
        "tangential_stiffness": Field(2e5, number(lo=0.0, lo_open=False), "cement tangential spring St [N/m]"),
        "threshold_mean": Field(2.5e-5, positive(), "mean rupture energy [J] (G: 5e-6 to 4.5e-5 J)"),
        "threshold_half_width": Field(2.0e-5, number(lo=0.0, lo_open=False),
                                      "half-width of the uniform rupture energies [J]"),
        "fade_time": Field(1e-5, number(lo=0.0, lo_open=False),
                           "time over which a broken cement's force fades to zero [s]"),
        "seed": Field(11, number(lo=0, lo_open=False, integer=True), "seed of the rupture energies"),
    },
    "preparation": {
        "friction": Field(0.0, number(lo=0.0, lo_open=False),
                          "friction during the isotropic compression (0: dense packing)"),
        "viscous_damping": Field(1e4, number(lo=0.0, lo_open=False), "global damping C [1/s]"),
        "gain": Field(1e-4, positive(), "isotropic servo gain [1/(Pa s)] (gain * pc: the gas's "
                                                  "initial rate, capped by max_rate)"),
        "max_rate": Field(100.0, positive(), "cap of the servo's strain rate [1/s]"),
        "tolerance": Field(0.01, number(0.0, 1.0), "relative pressure tolerance of the end state"),
        "kinetic_ratio": Field(1e-4, dc.tolerance(), "end state: kinetic / elastic contact energy below this"),
        "checks": Field(3, number(lo=1, lo_open=False, integer=True),
                        "consecutive checks (every check_every steps) meeting both criteria"),
        "check_every": Field(200, number(lo=1, lo_open=False, integer=True), "steps between checks"),
        "max_steps": Field(200000, number(lo=1, lo_open=False, integer=True),
                           "the preparation stops here even if not converged (reported)"),
    },
    "loading": {
        "confining_pressure": Field(1e6, positive(), "pc [Pa]: preparation pressure and lateral stress"),
        "axis": Field("z", choice("x", "y", "z"), "axial (loading) axis: x, y or z"),
        "strain_rate": Field(2.0, positive(), "axial strain rate [1/s] (compression)"),
        "strain": Field(0.05, number(dc.MIN_STRAIN, 0.5, lo_open=False), "final axial strain"),
        "gain": Field(3e-4, positive(), "lateral stress servo gain [1/(Pa s)]"),
        "max_rate": Field(20.0, positive(), "cap of the lateral strain rates [1/s]"),
    },
    "run": run_section("critical (Rayleigh / cement) step",
                       "must exceed the cement's largest stretch sqrt(2 E_max / Sn); auto = 0.1 x the mean "
                       "radius sample.radius"),
    "checkpoint": CHECKPOINT_SECTION,
    "output": output_deck.output_section(samples=output_deck.samples("rows of the loading series"),
                                         plot_figures="triaxial.png"),
}, checks=(sample_checks, run_checks, pressure_checks))

COLUMNS = ("step", "time", "eps_axial", "eps_vol", "q", "p", "sigma_axial", "sigma_lateral_1",
           "sigma_lateral_2", "broken_fraction", "cements_intact", "cements_fading", "coordination",
           "kinetic_energy")
UNITS = ("1", "s", "1", "1", "Pa", "Pa", "Pa", "Pa", "Pa", "1", "1", "1", "1", "J")
INT_COLUMNS = ("step", "cements_intact", "cements_fading")
DESCRIPTION = ("pardem triaxial series: one row per sample of the loading: axial and volumetric strain "
               "(compression / contraction positive), deviator q, mean stress p, axial and lateral "
               "stresses (compression positive), cement counts and broken fraction, coordination, "
               "kinetic energy; one dataset per column with its 'units'")


def skin(deck):
    """The Verlet skin [m] of the deck ("auto" = 0.1 x the mean radius)."""
    v = deck["run"]["skin"]
    return 0.1 * deck["sample"]["radius"] if v == "auto" else float(v)


def sample_gas(deck):
    """Centres [N, 3], radii [N], velocities [N, 3] and the cubic cell edge [m] of the initial gas."""
    s = deck["sample"]
    m, R = s["per_edge"], s["radius"]
    rng = np.random.default_rng(s["seed"])
    n = m**3
    radii = R * rng.uniform(1.0 - s["dispersity"], 1.0 + s["dispersity"], n)
    mean_volume = 4.0 / 3.0 * math.pi * float(np.mean(radii**3))
    a = (mean_volume / s["gas_fraction"]) ** (1.0 / 3.0)
    if a < 2.0 * R * (1.0 + s["dispersity"]) * 1.02:
        raise ValueError(f"sample.gas_fraction = {s['gas_fraction']}: the lattice spacing {a:.4g} m "
                         "leaves the largest spheres overlapping; lower it")
    g = (np.arange(m) + 0.5) * a
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    jitter = 0.5 * (a - 2.0 * R * (1.0 + s["dispersity"]))
    pos += rng.uniform(-jitter, jitter, pos.shape)
    vel = rng.normal(0.0, s["gas_speed"], pos.shape)
    return pos, radii, vel, m * a


def contact_params(deck, friction, cemented):
    c, k = deck["contacts"], deck["cement"]
    p = {"young": c["young"], "poisson": c["poisson"], "friction": float(friction),
         "restitution": c["restitution"]}
    if cemented:
        p.update(cement_normal=k["normal_stiffness"], cement_tangential=k["tangential_stiffness"],
                 cement_fade_time=k["fade_time"])
    return p


def time_step(deck):
    """``dt_fraction`` of the critical step of the cemented contacts of the smallest sphere [s]."""
    s = deck["sample"]
    prm = law_params("hertz_mindlin", contact_params(deck, 0.0, True))
    r_min = s["radius"] * (1.0 - s["dispersity"])
    return deck["run"]["dt_fraction"] * critical_time_step(
        "hertz_mindlin", prm, np.array([r_min]), s["density"])


def check_deck(deck):
    """ValueError for a deck that cannot run (cement reach against the skin, gas spacing)."""
    k = deck["cement"]
    prm = law_params("hertz_mindlin", contact_params(deck, 0.0, True))
    cementing.check(prm, k["threshold_mean"], k["threshold_half_width"],
                    skin(deck))
    sample_gas(deck)


def build(comm, deck):
    """The initial gas as a granular case with the isotropic servo at pc and viscous damping."""
    check_deck(deck)
    pos, radii, vel, edge = sample_gas(deck)
    pr, ld = deck["preparation"], deck["loading"]
    servo = (ld["confining_pressure"], pr["gain"], pr["max_rate"])
    system = System(Particles(pos, radii, deck["sample"]["density"], velocities=vel),
                    contacts=ContactModel("hertz_mindlin", contact_params(deck, pr["friction"], False)),
                    cell=Cell(np.zeros(3), np.full(3, edge), servo=servo),
                    integration=Integration(dt=time_step(deck), viscous_damping=pr["viscous_damping"]),
                    decomposition=Decomposition(slab_axis=AXES.index(deck["run"]["slab_axis"]), skin=skin(deck),
                                                balance_every=200))
    return granular.build_case(comm, system)


def prepare(case, deck, progress=None, state=None, operations=(), stop=None):
    """Run the isotropic compression to equilibrium at pc; returns a dict of the end state.

    progress: a ``pardem.io.progress.Progress`` (or None). state: the protocol's dict (``met``:
    consecutive checks met, ``checked_step``: the step of the last check counted), updated as the
    run goes, so that a run restored from a checkpoint written during the preparation continues
    it (completing the check interval it was in). operations: of every run (writers); stop: the
    step at which ``StepLimit`` ends the run early.
    """
    sim, pr = case.sim, deck["preparation"]
    pc = deck["loading"]["confining_pressure"]
    every, most = pr["check_every"], pr["max_steps"]
    st = {} if state is None else state
    st.setdefault("met", 0)
    st.setdefault("checked_step", -1)
    while True:
        step = sim.step_count
        at_check = step > 0 and (step % every == 0 or step >= most)
        if at_check and st["checked_step"] != step:
            p = -float(np.trace(sim.stress)) / 3.0
            ke = sim.kinetic_energy()
            el = sim.contacts.global_sums(sim.comm)[1]
            ok = abs(p - pc) <= pr["tolerance"] * pc and ke <= pr["kinetic_ratio"] * max(el, 1e-300)
            st["met"] = st["met"] + 1 if ok else 0
            st["checked_step"] = step
            if progress is not None:
                progress.report(step, f"preparation: p = {p:.4g} Pa (target {pc:.4g}), kinetic/elastic = "
                                      f"{ke / max(el, 1e-300):.3g}")
        if (at_check and st["met"] >= pr["checks"]) or step >= most:
            break
        n = min(every - step % every, most - step)
        if stop is not None:
            if step >= stop:
                raise StepLimit(f"stopped at step {step} (--steps {stop}), in the preparation")
            n = min(n, stop - step)
        sim.run(n, operations)
    return {"steps": sim.step_count, "converged": st["met"] >= pr["checks"],
            "pressure": -float(np.trace(sim.stress)) / 3.0, "kinetic_energy": sim.kinetic_energy(),
            "solid_fraction": solid_fraction(sim), "coordination": coordination(sim)}


def solid_fraction(sim):
    """Sphere volume over cell volume (overlap lenses not removed: they are ~1e-3 of it)."""
    e = sim.elements
    v = 4.0 / 3.0 * math.pi * exact_sum(sim.comm, e.radius[:e.n_owned] ** 3)
    return v / sim.cell.volume


def coordination(sim):
    n = float(sim.comm.sum(float(sim.elements.n_owned)))
    return 2.0 * float(sim.comm.sum(sim.contacts.n_touching)) / n


def cement(case, deck):
    """Switch to the loading's friction and cemented contacts, remove the damping, cement every
    contact. Returns the global number of cements (also kept in ``case.extras``)."""
    k = deck["cement"]
    set_contact_params(case.sim, contact_params(deck, deck["contacts"]["friction"], True))
    case.sim.viscous_damping = 0.0
    n = cementing.cement_contacts(case.sim, k["threshold_mean"], k["threshold_half_width"], k["seed"])
    case.extras["cemented_pairs"] = n
    return n


def start_loading(case, deck):
    """Replace the isotropic servo by the triaxial one; the reference state of the strains."""
    sim, ld = case.sim, deck["loading"]
    axis = AXES.index(ld["axis"])
    sim.cell.servo = PeriodicCell.triaxial_servo(axis, -ld["strain_rate"], ld["confining_pressure"],
                                                 ld["gain"], ld["max_rate"])
    sim.cell.control(sim.stress)     # the first step already moves at the loading's rates
    case.extras["triaxial_reference"] = {"length": sim.cell.length.tolist(), "axis": axis,
                                            "step": sim.step_count}


def loading_steps(case, deck):
    """Steps from the start of the loading to the final axial strain."""
    ld = deck["loading"]
    # each step multiplies the axial edge by (1 - rate dt): eps_a = 1 - (1 - rate dt)^steps
    return int(math.ceil(math.log1p(-ld["strain"]) / math.log1p(-ld["strain_rate"] * case.sim.dt)))


def sample(case):
    """One row of ``COLUMNS`` (collective)."""
    sim = case.sim
    ref = case.extras["triaxial_reference"]
    axis = ref["axis"]
    L0 = np.asarray(ref["length"])
    L = sim.cell.length
    s = sim.stress
    lat = [b for b in range(3) if b != axis]
    sig_a = -float(s[axis, axis])
    sig_l = [-float(s[b, b]) for b in lat]
    intact, fading = cementing.cement_counts(sim)
    n0 = case.extras.get("cemented_pairs", 0)
    return {"step": sim.step_count, "time": sim.time,
            "eps_axial": 1.0 - L[axis] / L0[axis], "eps_vol": 1.0 - float(np.prod(L / L0)),
            "q": sig_a - 0.5 * (sig_l[0] + sig_l[1]), "p": -float(np.trace(s)) / 3.0,
            "sigma_axial": sig_a, "sigma_lateral_1": sig_l[0], "sigma_lateral_2": sig_l[1],
            "broken_fraction": 1.0 - intact / n0 if n0 else 0.0, "cements_intact": intact,
            "cements_fading": fading, "coordination": coordination(sim),
            "kinetic_energy": sim.kinetic_energy()}


def load(case, deck, steps=None, rows=None, operations=(), progress=None, stop=None, on_row=None):
    """Run the triaxial loading (``steps`` from its start; default to the final strain), sampling
    ``output.samples`` rows (``rows``: those of the loading so far, for a restored case). Returns
    the rows. progress: a ``pardem.io.progress.Progress``; on_row(row) after every row; stop: the
    step at which ``StepLimit`` ends the run early (the rows are those of the uncut run)."""
    sim = case.sim
    total = loading_steps(case, deck) if steps is None else int(steps)
    start = case.extras["triaxial_reference"]["step"]
    every = max(1, total // deck["output"]["samples"])

    def report(row):
        if progress is not None:
            progress.report(row["step"], f"loading {row['step'] - start}/{total}: eps_a = {row['eps_axial']:.4f}, "
                                         f"q = {row['q']:.4g} Pa, eps_v = {row['eps_vol']:.4g}, "
                                         f"broken = {row['broken_fraction']:.3f}")
        if on_row is not None:
            on_row(row)
    sampler = RowSampler(lambda: sample(case), every, start + total, [] if rows is None else rows, report)
    if not sampler.rows:
        sampler(sim)
    n = start + total - sim.step_count
    if stop is not None and n > 0:
        if sim.step_count >= stop:
            raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), in the loading")
        n = min(n, stop - sim.step_count)
    sim.run(max(n, 0), [sampler, *operations])     # n < 0: restored past the end
    if sim.step_count < start + total:
        raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), in the loading")
    return sampler.rows


def summary(rows, pc):
    """Peak deviator and its strain, final values, the lateral stress error over the loading."""
    q = np.array([r["q"] for r in rows])
    ea = np.array([r["eps_axial"] for r in rows])
    lat = np.array([[r["sigma_lateral_1"], r["sigma_lateral_2"]] for r in rows])
    k = int(np.argmax(q))
    settled = ea >= 0.1 * ea[-1] if ea[-1] > 0 else np.ones(len(rows), bool)
    err = np.abs(lat[settled] - pc) / pc
    return {"peak_deviator": float(q[k]), "strain_at_peak": float(ea[k]),
            "peak_stress_ratio": float(q[k] / pc), "final_axial_strain": float(ea[-1]),
            "final_deviator": float(q[-1]), "final_volumetric_strain": float(rows[-1]["eps_vol"]),
            "max_contraction": float(max(r["eps_vol"] for r in rows)),
            "final_broken_fraction": float(rows[-1]["broken_fraction"]),
            "lateral_stress_error_mean": float(err.mean()) if err.size else None,
            "lateral_stress_error_max": float(err.max()) if err.size else None}
