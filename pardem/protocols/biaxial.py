"""2D biaxial compression with rigid granular platens and flexible membranes.

Protocol, for each confining pressure ``pc`` of ``loading.confining_pressures`` (any number of ranks):

1. **Preparation** (``pardem.protocols.stages.prepare`` in 2D): the deck's gas of disks-in-plane
   spheres (``sample``: bidisperse by default, R = 0.11 / 0.09 mm, i.e. 0.1 mm +- 10 %) compressed
   frictionless by the pressure servo of the periodic cell to static equilibrium at ``pc``.
2. **Opening**: the packing copied ``replicate.copies = [k_x, k_y]`` times first
   (``pardem.engine.replicate``: a larger sample without a new preparation, as in the response
   protocol; default [1, 1], none); then (``pardem.engine.open_cell.open_axes``) x and y are no longer periodic; with
   ``lo``, ``L`` the former cell along y, the platen lines are ``y_b = lo + h`` and
   ``y_t = lo + L - h`` (``h = loading.platen_offset`` mean radii); grains whose centres lie within
   ``loading.platen_halfwidth`` mean radii (default 1: "within R") of a line form that platen,
   grains beyond the platens are removed (so no pair crosses the former y boundary; along x the
   lateral sides are free, the contacts across the former x boundary are dropped).
3. **Friction on**: the loading's friction ``material.friction`` and restitution
   ``loading.restitution`` (contact damping), global damping ``loading.damping``.
4. **Platens**: each is rigid (``pardem.engine.fixes.PrescribedVelocity`` on its grains, x, y and
   the spin about z imposed): they move along y towards each other at ``v/2`` each, with
   ``v = loading.strain_rate H0`` (so the axial strain ``eps_a = 1 - H / H0 = rate t`` exactly,
   ``H`` the distance between the platen lines), and **do not move along x** (rough platens:
   the grains at the sample's ends cannot slide along the platen, as in a test between rough
   rigid platens; a platen free to translate along x would need a rigid-body fix with a
   collective force sum per step, and would not remove the end restraint either: the platen
   stays one rough rigid body, and by symmetry its net x force is about zero anyway). The end
   restraint shows: in the 300-grain square sample of ``drivers/biaxial_short.toml`` the
   Love-Weber lateral stress is pc within 1 % at eps_a < 0.2 % and rises with the deviator
   (about pc + 0.2 q): the rough ends confine the sample's lateral expansion. Taller samples
   (or the 10,000-grain deck) reduce the platens' share.
5. **Membranes** (``pardem.engine.membrane_load.MembraneLoad``, a load fix): one chain per lateral
   side (``pardem.physics.membrane``: search distance ``loading.membrane_distance`` mean radii),
   loaded by ``pc`` over the thickness ``t`` of the 2D convention (the mean diameter), rebuilt
   every ``loading.membrane_every`` steps alternately from the bottom and from the top.
6. ``loading.settle_steps`` steps with the platens at rest, then the loading to ``loading.strain``.

Measures (``sample``; compression positive): the sample's area ``A`` is the polygon through the
membrane grains' centres closed by the platens (``MembraneLoad.area``); ``eps_v = 1 - A' / A0'``
(contraction positive) with ``A'`` the area tracked across the chain rebuilds
(``MembraneLoad.tracked_area``: a rebuild's change of outline is not a change of volume); the stress is the Love-Weber stress of all contacts over the sample's
volume ``A t``, ``sigma = sum_c d f / (A t)`` (tension positive; the engine's exact sums). In
static equilibrium it is the boundary sum of the membrane loads (``p t`` times the area their
chains enclose) and of the platens' reactions, so ``sigma_l = -sigma_xx`` is the lateral stress
the membranes transmit up to the platens' share, O(R / H): the x-fixed platen rows keep the
lateral prestress of the periodic state (``sigma_*_inner``: the same without the contacts
between two platen grains, whose boundary is then the platen grains' centres, short of the
membrane's half end segments; the two bracket the platens' effect: +-6 % on a 12-row hexagonal
lattice, +0.5 / -6 % on the 300-grain random sample of ``drivers/biaxial_short.toml`` at the
start of the loading);
``sigma_a = -sigma_yy``, ``q = sigma_a -
sigma_l``, ``s = (sigma_a + sigma_l) / 2``, the mobilised friction ``sin phi = q / (2 s)``; also
the platens' axial stress from their reactions (mean of the two over ``t A / H``), the
coordination, the fraction of sliding contacts (``|f_t| >= (1 - 1e-9) mu f_n``), the membrane
grain count and the kinetic energy.

Angles (``angles``): peak friction angle at the largest ``sin phi``; residual friction angle the
mean ``sin phi`` over the last ``residual_fraction`` of the axial strain; dilatancy angle from
``sin psi = -d eps_v / d gamma`` with ``d gamma = 2 d eps_a - d eps_v`` (2D, ``eps_1 = eps_a``,
``eps_3 = eps_v - eps_a``), its largest value over the loading (slopes over windows of
``~ 5 %`` of the samples).

Localisation (``localisation``): at each ``localisation.strains`` ``s`` the increment over the
window ``[s - window, s]``: the least-squares displacement gradient of every grain over its
touching contacts of the window's start (``pardem.physics.local_strain``), its shear and
volumetric strain and rotation, each grain's own rotation increment (spin about z), the band of
the shear field outside the platens (``pardem.physics.shear_band.detect``: angle, width,
centre) and the predictions from the measured peak friction and dilatancy angles (Mohr-Coulomb
45 + phi/2, Roscoe 45 + psi/2, Arthur 45 + (phi + psi)/4).
"""
import dataclasses
import math

import numpy as np

from pardem.config import DeckError, Field, Schema, boolean, number, number_list, positive
from pardem.engine import cement as cementing
from pardem.engine import fixes, granular
from pardem.engine.contacts import KEY_BASE
from pardem.engine.membrane_load import MembraneLoad
from pardem.engine.open_cell import open_axes
from pardem.engine.system import set_contact_params
from pardem.engine.replicate import replicate
from pardem.triggers import At, Or
from pardem.parallel.exact_sum import exact_sum
from pardem.physics import hertz_mindlin as hm
from pardem.physics import local_strain, shear_band
from pardem.physics.timestep import rayleigh_time_step
from pardem.protocols import deck_checks as dc
from pardem.engine.packing import contact_forces
from pardem.protocols import isotropic, stages
from pardem.protocols.granular_output import CHECKPOINT_SECTION, REPLICATE_SECTION, StepLimit, run_section
from pardem.protocols import output_deck

ISO = isotropic.SCHEMA


def _default(section, key, value):
    return dataclasses.replace(ISO[section][key], default=value)


def biaxial_checks(deck):
    """The time step, the loading's length and platen speed, and the localisation windows."""
    s, mat, ld, loc = deck["sample"], deck["material"], deck["loading"], deck["localisation"]
    r_min = min(s["radii"])
    dt = deck["run"]["dt_fraction"] * rayleigh_time_step(r_min, s["density"], mat["shear_modulus"],
                                                         mat["poisson"])
    dc.check_normal(dt, "the time step", "s", "run.dt_fraction, material.shear_modulus, sample.density")
    # the sample's height at the densest packing of the smallest grains (the shortest height)
    edge = math.sqrt(s["n"] * math.pi * r_min * r_min / (math.pi / math.sqrt(12.0)) * s["aspect_ratio"]) \
        * deck["replicate"]["copies"][1]
    dc.check_rate(ld["strain_rate"], edge, math.sqrt(stages.young_modulus(mat) / s["density"]),
                  "loading.strain_rate", "material.shear_modulus, sample.density")
    steps = len(ld["confining_pressures"]) * (ld["strain"] / (ld["strain_rate"] * dt) + ld["settle_steps"]
                                              + deck["preparation"]["max_steps"])
    dc.check_steps(steps, "loading.strain, loading.strain_rate, run.dt_fraction", "the loading")
    dc.check_drag(ld["damping"], dt, "loading.damping")
    if ld["platen_offset"] < ld["platen_halfwidth"]:
        raise DeckError(f"loading.platen_offset = {ld['platen_offset']} is below loading.platen_halfwidth = "
                        f"{ld['platen_halfwidth']}: the platens would reach across the former boundary")
    if loc["enabled"]:
        for k, e in enumerate(loc["strains"]):
            if not loc["window"] < e <= ld["strain"]:
                raise DeckError(f"localisation.strains[{k}] = {e}: expected a strain in (localisation.window = "
                                f"{loc['window']}, loading.strain = {ld['strain']}]")


SCHEMA = Schema({
    "sample": {**ISO["sample"], "n": _default("sample", "n", 10000),
               "radii": _default("sample", "radii", [0.11e-3, 0.09e-3]),
               "aspect_ratio": Field(1.0, number(0.25, 4.0, lo_open=False, hi_open=False),
                                     "height over width of the periodic cell the sample is prepared in "
                                     "(the servo compresses it isotropically: the sample keeps it)")},
    "material": ISO["material"],
    "preparation": ISO["preparation"],
    "equilibrium": ISO["equilibrium"],
    "replicate": REPLICATE_SECTION,
    "loading": {
        "confining_pressures": Field([1e7], number_list(positive()),
                                     "confining pressures pc [Pa]: each prepares its packing at pc and loads it"),
        "strain_rate": Field(1.0, positive(), "axial strain rate [1/s] (platen speed / initial height)"),
        "strain": Field(0.1, number(dc.MIN_STRAIN, 0.5, lo_open=False), "final axial strain"),
        "restitution": Field(0.5, number(0.0, 1.0, hi_open=False),
                             "normal restitution of the contacts during the loading (contact damping)"),
        "damping": Field(0.0, number(lo=0.0, lo_open=False), "global viscous damping C [1/s] of the loading"),
        "platen_offset": Field(2.0, positive(), "distance of the platen lines from the former cell's y "
                                                "boundaries [mean radii]"),
        "platen_halfwidth": Field(1.0, positive(), "grains within this distance of a platen line form the "
                                                   "platen [mean radii]"),
        "membrane_distance": Field(2.5, number(1.0, 10.0), "search distance r_m of the membrane chain "
                                                           "[mean radii]"),
        "membrane_every": Field(100, number(lo=1, lo_open=False, integer=True),
                                "steps between membrane rebuilds (alternately from bottom and top)"),
        "settle_steps": Field(2000, number(lo=0, lo_open=False, integer=True),
                              "steps with the platens at rest and the membranes on before the loading"),
        "residual_fraction": Field(0.2, number(0.0, 1.0), "residual friction angle: mean over this last "
                                                          "fraction of the axial strain"),
    },
    "cement": {
        "enabled": Field(False, boolean, "cement every contact when the friction is switched on (item 5: "
                                         "cemented samples; pardem.engine.cement)"),
        "normal_stiffness": Field(1e7, positive(), "cement normal spring Sn [N/m]"),
        "tangential_stiffness": Field(1e7, number(lo=0.0, lo_open=False), "cement tangential spring St [N/m]"),
        "threshold_mean": Field(2e-9, positive(), "mean rupture energy [J]"),
        "threshold_half_width": Field(1e-9, number(lo=0.0, lo_open=False), "half-width of the uniform rupture "
                                                                          "energies [J]"),
        "fade_time": Field(1e-6, number(lo=0.0, lo_open=False), "time a broken cement's force fades over [s]"),
        "seed": Field(11, number(lo=0, lo_open=False, integer=True), "seed of the rupture energies"),
    },
    "localisation": {
        "enabled": Field(True, boolean, "measure the incremental strain fields and the shear band"),
        "strains": Field([0.05, 0.1], number_list(positive()), "axial strains at the end of each window"),
        "window": Field(0.01, positive(), "axial strain increment of a window"),
        "band_fraction": Field(0.1, number(0.0, 1.0), "the most sheared fraction of grains defining the band"),
    },
    "run": run_section("Rayleigh critical step", "auto = 0.2 x the smallest radius"),
    "checkpoint": CHECKPOINT_SECTION,
    "output": output_deck.output_section(samples=output_deck.samples("rows of the loading series per pressure"),
                                         plot_figures="biaxial.png and the localisation maps"),
}, checks=(isotropic.sample_checks, biaxial_checks, isotropic.pressure_checks))

COLUMNS = ("step", "time", "pressure_index", "pc", "eps_axial", "eps_vol", "sigma_axial", "sigma_lateral",
           "sigma_axial_inner", "sigma_lateral_inner", "q", "s", "sin_phi", "sigma_axial_platens", "coordination", "sliding_fraction", "membrane_grains",
           "n_grains", "cements_intact", "cements_fading", "cements_broken", "broken_fraction", "kinetic_energy")
UNITS = ("1", "s", "1", "Pa", "1", "1", "Pa", "Pa", "Pa", "Pa", "Pa", "Pa", "1", "Pa", "1", "1", "1", "1", "1", "1",
         "1", "1", "J")
INT_COLUMNS = ("step", "pressure_index", "membrane_grains", "n_grains", "cements_intact", "cements_fading",
               "cements_broken")
DESCRIPTION = ("pardem biaxial series: one row per sample of the loading of each confining pressure: axial "
               "strain 1 - H/H0, volumetric strain 1 - A/A0 (membrane polygon area carried across the chain rebuilds, contraction positive), "
               "Love-Weber stresses of the contacts over the sample's area times the thickness (compression "
               "positive; _inner: without the contacts between two platen grains), deviator q, mean in-plane stress s, sin phi = q / 2s, the platens' axial stress from "
               "their reactions, coordination, sliding-contact fraction, membrane grains, grains, cement counts "
               "(intact, fading, broken = made - intact) and broken fraction (cemented samples), kinetic energy")


def iso_deck(deck):
    """The isotropic protocol's deck for the preparation (2D)."""
    return {"domain": {"dimension": 2}, "sample": deck["sample"], "material": deck["material"],
            "preparation": deck["preparation"], "equilibrium": deck["equilibrium"], "run": deck["run"]}


def mean_radius(deck):
    s = deck["sample"]
    f = np.asarray(s["fractions"], dtype=float)
    return float(np.dot(f / f.sum(), s["radii"]))


# -- the stages ------------------------------------------------------------------------------

# the stages of one confining pressure, in order (``pardem.protocols.stages.run_stages``): the
# frictionless preparation (resumable: ``stages.prepare``), the opening (no step), the settling
# and the loading (both resume from the pressure's state and a checkpoint's step)
STAGES = ("prepare", "open", "settle", "load")


def prepare(comm, deck, pc, step=0, time=0.0, progress=None):
    """The periodic 2D packing at static equilibrium at ``pc`` (frictionless), its steps counted
    from ``step`` (time ``time``); ``(case, info)``."""
    iso = iso_deck(deck)
    case = stages.build_gas(comm, iso)
    if step:
        granular.continue_clock(case.sim, step, time)
    return stages.prepare(comm, iso, float(pc), case=case, progress=progress)


def open_sample(comm, case, deck):
    """Copy the packing ``replicate.copies`` times (``pardem.engine.replicate``: no new preparation),
    open x and y, keep the grains between the platens; returns ``(case, geometry)`` with the
    platen lines ``y_bottom``, ``y_top`` [m] and the platens' gids (new numbering)."""
    ld = deck["loading"]
    R = mean_radius(deck)
    step, clock = case.sim.step_count, case.sim.time
    k = deck["replicate"]["copies"]
    if k != [1, 1]:
        case = replicate(comm, case, k)
    lo, L = float(case.sim.cell.lo[1]), float(case.sim.cell.length[1])
    yb, yt = lo + ld["platen_offset"] * R, lo + L - ld["platen_offset"] * R
    hw = ld["platen_halfwidth"] * R
    opened = open_axes(comm, case, ("x", "y"), keep=lambda x: (x[:, 1] >= yb - hw) & (x[:, 1] <= yt + hw))
    granular.continue_clock(opened.sim, step, clock)
    e = opened.sim.elements
    n = e.n_owned
    parts = comm.allgather((e.gid[:n].copy(), e.x[:n, 1].copy()))
    gid = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    geo = {"y_bottom": yb, "y_top": yt, "halfwidth": hw, "mean_radius": R,
           "bottom": np.sort(gid[np.abs(y - yb) <= hw]).tolist(), "top": np.sort(gid[np.abs(y - yt) <= hw]).tolist(),
           "n_before": int(opened.extras["opened"]["n_before"]), "n_grains": int(len(gid))}
    return opened, geo


def loading_params(deck):
    """The loading's contact parameters (friction on; cemented when ``cement.enabled``)."""
    mat, ld, k = deck["material"], deck["loading"], deck["cement"]
    p = stages.contact_params(mat, mat["friction"], ld["restitution"])
    if k["enabled"]:
        p.update(cement_normal=k["normal_stiffness"], cement_tangential=k["tangential_stiffness"],
                 cement_fade_time=k["fade_time"])
    return p


def install(case, deck, pc, geo, membrane_state=None, moving=False, restored=False):
    """Put the membrane and the two platens on ``case.sim``: returns ``(membrane, bottom_fix,
    top_fix)``; the platens move when ``moving``. ``restored``: a case read back from a checkpoint
    (its forces are the stored ones, fixes included): the fixes are put in the uninterrupted
    run's order ``[membrane, plane, bottom, top]`` without being applied again."""
    ld = deck["loading"]
    R = geo["mean_radius"]
    t = case.sim.cell.thickness
    if membrane_state is None:
        mem = MembraneLoad(geo["bottom"], geo["top"], pc, t, ld["membrane_distance"] * R, ld["membrane_every"])
    else:
        mem = MembraneLoad.from_state(membrane_state)
    v = platen_speed(deck, geo) if moving else 0.0
    bottom = fixes.PrescribedVelocity(geo["bottom"], (0.0, 0.5 * v, 0.0), angular_velocity=(0.0, 0.0, 0.0),
                                      dofs="xy", rotations="z")
    top = fixes.PrescribedVelocity(geo["top"], (0.0, -0.5 * v, 0.0), angular_velocity=(0.0, 0.0, 0.0),
                                   dofs="xy", rotations="z")
    if restored:
        case.sim.fixes.insert(0, mem)
        case.sim.fixes.extend([bottom, top])
    else:
        fixes.add(case.sim, mem, bottom, top)
    return mem, bottom, top


def platen_speed(deck, geo):
    """Relative speed of the platens [m/s]: ``strain_rate * H0``."""
    return deck["loading"]["strain_rate"] * (geo["y_top"] - geo["y_bottom"])


def set_moving(platens, deck, geo):
    v = platen_speed(deck, geo)
    platens[0].velocity[:, 1] = 0.5 * v
    platens[1].velocity[:, 1] = -0.5 * v


def start_loading(case, deck, geo, mem):
    """Friction on (loading contacts), loading damping, and with ``cement.enabled`` a cement on
    every contact (``pardem.engine.cement``: unstressed, rupture energies uniform in mean +-
    half-width, a function of the seed and the gid pair). Returns the number of cements (0)."""
    set_contact_params(case.sim, loading_params(deck))
    case.sim.viscous_damping = float(deck["loading"]["damping"])
    k = deck["cement"]
    n = 0
    if k["enabled"]:
        n = cementing.cement_contacts(case.sim, k["threshold_mean"], k["threshold_half_width"], k["seed"])
    case.extras["cemented_pairs"] = n
    return n


def loading_steps(deck, dt):
    ld = deck["loading"]
    return int(math.ceil(ld["strain"] / (ld["strain_rate"] * dt) - 1e-9))


def event_steps(deck, dt, start):
    """The steps of the localisation windows' starts and ends: ``[(start_step, end_step)]``."""
    loc, ld = deck["localisation"], deck["loading"]
    if not loc["enabled"]:
        return []
    per = ld["strain_rate"] * dt
    return [(start + int(round((e - loc["window"]) / per)), start + int(round(e / per))) for e in loc["strains"]]


def settle(case, deck, st, operations=(), stop=None):
    """The settling steps with the platens at rest (from ``st["settle_start"]``)."""
    sim = case.sim
    end = st["settle_start"] + deck["loading"]["settle_steps"]
    n = end - sim.step_count
    if stop is not None and n > 0:
        if sim.step_count >= stop:
            raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), settling pressure {st['index']}")
        n = min(n, stop - sim.step_count)
    if n > 0:
        sim.run(n, operations)
    if sim.step_count < end:
        raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), settling pressure {st['index']}")


def reference(case, mem, geo, deck):
    """The loading's reference state: step, height H0, area A0, platen speed."""
    sim = case.sim
    mem.positions = mem.gather_positions(sim)
    return {"step": sim.step_count, "height": geo["y_top"] - geo["y_bottom"], "area": mem.tracked_area(),
            "speed": platen_speed(deck, geo)}


def load(case, deck, st, mem, platens, on_row, operations=(), stop=None, on_event=None, record=None,
         replay=False):
    """Run the loading of the pressure of ``st`` to ``loading.strain`` (from wherever it is),
    sampling ``output.samples`` rows through ``on_row(row)``; ``on_event(step)`` at each
    localisation window's start or end step (``event_steps``) not yet in ``st["events_done"]``.
    ``stop``: the step of ``--steps`` (``StepLimit``). ``record``: a ``CementRecord`` updated at
    every sample (cemented samples: when each cement broke). ``replay``: resumed from a stop
    signal's checkpoint, whose step's operations (a sample, the writers) have not run yet
    (``stages.replay``)."""
    sim = case.sim
    start = st["reference"]["step"]
    total = loading_steps(deck, sim.dt)
    end = start + total
    every = max(1, total // deck["output"]["samples"])
    sampler = Sampler(case, st, mem, platens, every, start, on_row, end, record)
    done = st.setdefault("events_done", [])
    marks = sorted({s for pair in event_steps(deck, sim.dt, start) for s in pair})

    def events():
        if on_event is not None and sim.step_count in marks and sim.step_count not in done:
            on_event(sim.step_count)
            done.append(sim.step_count)
    if replay:
        stages.replay(sim, [sampler, *operations])
    if sim.step_count == start:
        sampler(sim)
    events()
    while sim.step_count < end:
        nxt = min([m for m in marks if m > sim.step_count] + [end])
        if stop is not None:
            if sim.step_count >= stop:
                raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), loading pressure {st['index']}")
            nxt = min(nxt, stop)
        sim.run(nxt - sim.step_count, [sampler, *operations])
        events()
    sampler(sim)


# -- measures --------------------------------------------------------------------------------

def contact_measures(sim, platen_gids):
    """Collective, the same bits on any number of ranks (exact sums): the Love-Weber sums
    ``sum d_a F_b`` [N m] [2, 2] of the pairs that touch a grain outside the platens (the
    platens' internal contacts left out: they are the boundary, and the x-fixed platen rows keep
    the lateral prestress of the periodic state), contact and cement forces (cemented pairs apart
    included), the sliding fraction of the touching contacts (Mindlin force ``|f_t| >= (1 -
    1e-9) mu f_n``; a contact held by an intact cement does not slide), the coordination ``2
    N_c / N`` (touching contacts) and ``N``."""
    cf = contact_forces(sim, cement=True)
    mu = float(sim.contacts.params.friction)
    d, F = cf["branch"], cf["force"]
    inner = ~(np.isin(cf["gid_i"], platen_gids) & np.isin(cf["gid_j"], platen_gids))
    terms = np.column_stack([d[:, 0] * F[:, 0], d[:, 0] * F[:, 1], d[:, 1] * F[:, 0], d[:, 1] * F[:, 1]])[inner]
    lw = exact_sum(sim.comm, terms.reshape(-1, 4)).reshape(2, 2)
    # Coulomb's criterion on the Mindlin force; a contact held by an intact cement does not slide
    ft = cf["tangential"]
    free = cf["touching"] & ~cf["intact"]       # touching: fn > 0
    at_limit = np.sqrt(np.einsum("ij,ij->i", ft, ft)) >= (1.0 - 1e-9) * mu * cf["fn"]
    sliding = np.count_nonzero((mu > 0.0) & free & at_limit)
    touching = np.count_nonzero(cf["touching"])
    tot = sim.comm.sum(np.array([float(touching), float(sliding), float(sim.elements.n_owned)]))
    return lw, (float(tot[1] / tot[0]) if tot[0] else 0.0), 2.0 * float(tot[0]) / float(tot[2]), int(tot[2])


def sample(case, st, mem, platens, record=None):
    """One row of ``COLUMNS`` (collective); ``st``: the pressure's state (reference, index);
    ``record``: a ``CementRecord`` told which cements broke since its last update (cemented)."""
    sim = case.sim
    if not mem.positions:
        mem.positions = mem.gather_positions(sim)
    ref = st["reference"]
    k = sim.step_count - ref["step"]
    v = ref["speed"]
    H = ref["height"] - v * k * sim.dt
    A = mem.area()
    t = sim.cell.thickness
    lw, sliding, Z, n = contact_measures(sim, np.concatenate([mem.bottom, mem.top]))
    inner = lw / (A * t)
    sig = np.asarray(sim.contacts.global_sums(sim.comm)[0]).reshape(3, 3) / (A * t)
    sa, sl = -float(sig[1, 1]), -float(sig[0, 0])
    reac = sim.comm.sum(np.concatenate([platens[0].reaction, platens[1].reaction]))
    width = A / H
    sap = 0.5 * (float(reac[1]) - float(reac[4])) / (width * t)
    q, s = sa - sl, 0.5 * (sa + sl)
    intact, fading = cementing.cement_counts(sim)
    n0 = case.extras.get("cemented_pairs", 0)
    eps_a = 1.0 - H / ref["height"]
    if record is not None and n0:
        record.update(intact_cements(sim), eps_a, sim.step_count)
    return {"step": sim.step_count, "time": sim.time, "pressure_index": st["index"], "pc": st["pc"],
            "eps_axial": eps_a, "eps_vol": 1.0 - mem.tracked_area() / ref["area"],
            "sigma_axial": sa, "sigma_lateral": sl, "sigma_axial_inner": -float(inner[1, 1]),
            "sigma_lateral_inner": -float(inner[0, 0]), "q": q, "s": s, "sin_phi": q / (2.0 * s) if s > 0 else 0.0,
            "sigma_axial_platens": sap, "coordination": Z, "sliding_fraction": sliding,
            "membrane_grains": int(sum(len(c) for c in mem.chains.values())), "n_grains": n,
            "cements_intact": intact, "cements_fading": fading, "cements_broken": n0 - intact if n0 else 0,
            "broken_fraction": 1.0 - intact / n0 if n0 else 0.0,
            "kinetic_energy": sim.kinetic_energy()}


class Sampler:
    """Operation appending ``sample`` rows on the steps of ``trigger`` (an int period [steps]: its
    multiples, counted from step 0), at ``start`` and at ``end``, from ``start`` on; a run cut in
    pieces samples the steps of the uncut one. A step already sampled is not sampled again."""

    def __init__(self, case, st, mem, platens, trigger, start, on_row, end=None, record=None):
        self.case, self.st, self.mem, self.platens = case, st, mem, platens
        self.start, self.on_row, self.end = int(start), on_row, end
        self.trigger = Or([trigger, At([self.start] + ([] if end is None else [end]))])
        self.record = record
        self.last = -1

    def __call__(self, sim):
        step = sim.step_count
        if step < self.start or step == self.last:
            return
        self.last = step
        self.on_row(sample(self.case, self.st, self.mem, self.platens, self.record))


def peak_index(rows):
    """Index of the row of the largest mobilised friction ``sin phi`` (the peak)."""
    return int(np.argmax(np.clip(np.array([r["sin_phi"] for r in rows]), -1.0, 1.0)))


def angles(rows, residual_fraction=0.2):
    """Peak and residual friction angles and the largest dilatancy angle [deg] of one loading.

    ``phi_*`` from the sample's Love-Weber stresses (``sin_phi``); ``phi_*_boundary`` as a laboratory
    test measures them, from the platens' axial stress and the membrane's pressure pc
    (``(sigma_axial_platens - pc) / (sigma_axial_platens + pc)``). They differ by the rigid platens'
    end restraint, which raises the sample's mean lateral stress above pc."""
    ea = np.array([r["eps_axial"] for r in rows])
    ev = np.array([r["eps_vol"] for r in rows])
    sp = np.clip(np.array([r["sin_phi"] for r in rows]), -1.0, 1.0)
    sab = np.array([r["sigma_axial_platens"] for r in rows])
    pc = np.array([r["pc"] for r in rows])
    spb = np.clip((sab - pc) / (sab + pc), -1.0, 1.0)
    kb = int(np.argmax(spb))
    k = peak_index(rows)
    last = ea >= (1.0 - residual_fraction) * ea[-1]
    w = max(1, len(rows) // 20)
    dea, dev = ea[w:] - ea[:-w], ev[w:] - ev[:-w]
    ok = dea > 0
    sin_psi = -dev[ok] / (2.0 * dea[ok] - dev[ok]) if ok.any() else np.array([0.0])
    j = int(np.argmax(sin_psi))
    return {"phi_peak_deg": float(np.degrees(np.arcsin(sp[k]))), "strain_at_peak": float(ea[k]),
            "q_peak": float(rows[k]["q"]),
            "phi_residual_deg": float(np.degrees(np.arcsin(np.mean(sp[last])))),
            "phi_peak_boundary_deg": float(np.degrees(np.arcsin(spb[kb]))), "strain_at_peak_boundary": float(ea[kb]),
            "phi_residual_boundary_deg": float(np.degrees(np.arcsin(np.mean(spb[last])))),
            "psi_max_deg": float(np.degrees(np.arcsin(np.clip(sin_psi[j], -1.0, 1.0)))),
            "strain_at_psi_max": float(ea[w:][ok][j]) if ok.any() else 0.0,
            "final_eps_vol": float(ev[-1]),
            "lateral_stress_error_max": float(np.max(np.abs([r["sigma_lateral"] / r["pc"] - 1.0 for r in rows])))}


# -- cement damage ---------------------------------------------------------------------------

def intact_cements(sim):
    """The intact cements (collective): their pair keys (``engine.contacts.pair_keys``: the gid
    pair, lower gid first), each pair once, sorted, the same int64 array on every rank."""
    c = sim.contacts
    if c.history.shape[1] != hm.WIDTH_CEMENTED:
        return np.zeros(0, np.int64)
    ok = c.counted_once(sim.elements.n_owned) & (c.history[:, hm.CEMENT_STATE] > 0.0)
    return np.sort(np.concatenate(sim.comm.allgather(np.asarray(c.keys[ok], dtype=np.int64).copy())))


def key_pairs(keys):
    """Gid pairs [m, 2] (int64) of pair keys [m]."""
    keys = np.asarray(keys, dtype=np.int64)
    return np.column_stack([keys // KEY_BASE, keys % KEY_BASE])


class CementRecord:
    """When each cement of a loading broke. The cement law keeps no rupture time (its state goes
    from +1 to fading to 0), so the record is made from the series: ``initial`` are the keys of
    the cements made when the friction was switched on; at each sample (``update``) the cements
    of ``initial`` no longer intact that are not yet recorded are appended with the sample's axial
    strain and step: each broke in the sampling interval before (the resolution is
    ``loading.strain / output.samples``). A cement never heals (no cement is made during the
    loading), so the record only grows; broken during the settling = recorded at eps_a = 0."""

    def __init__(self, initial, keys=(), strain=(), step=()):
        self.initial = np.sort(np.asarray(initial, dtype=np.int64))
        self.keys = np.asarray(keys, dtype=np.int64)
        self.strain = np.asarray(strain, dtype=np.float64)
        self.step = np.asarray(step, dtype=np.int64)

    def update(self, intact, eps_axial, step):
        """``intact``: the keys of the intact cements now (``intact_cements``)."""
        gone = np.setdiff1d(self.initial, intact, assume_unique=True)
        new = np.setdiff1d(gone, self.keys)
        if len(new):
            self.keys = np.concatenate([self.keys, new])
            self.strain = np.concatenate([self.strain, np.full(len(new), float(eps_axial))])
            self.step = np.concatenate([self.step, np.full(len(new), int(step), dtype=np.int64)])

    def per_grain(self, gid):
        """Broken cements per grain of the sorted gids ``gid`` [n] (int64 [n])."""
        ends = key_pairs(self.keys).ravel()
        return np.bincount(np.searchsorted(gid, ends), minlength=len(gid)).astype(np.int64)

    def state(self):
        """Arrays for a checkpoint's series (``from_state`` reads them back)."""
        return {"initial": self.initial, "keys": self.keys, "strain": self.strain, "step": self.step}

    @classmethod
    def from_state(cls, st):
        return cls(st["initial"], st["keys"], st["strain"], st["step"])


def cement_damage(rows, record=None):
    """The damage of one cemented loading (``rows``: its series): cements at the start, broken at
    the end, the broken fraction at the peak (``peak_index``) and at the end, and from the
    ``record`` the axial strains by which 10 % and 50 % of the finally broken had broken."""
    n0 = int(rows[0]["cements_intact"] + rows[0]["cements_broken"])
    k = peak_index(rows)
    out = {"cements_at_start": n0, "broken_at_end": int(rows[-1]["cements_broken"]),
           "broken_fraction_at_peak": float(rows[k]["broken_fraction"]), "strain_at_peak": float(rows[k]["eps_axial"]),
           "broken_fraction_at_end": float(rows[-1]["broken_fraction"])}
    if record is not None and len(record.strain):
        s = np.sort(record.strain)
        out["strain_10_percent_broken"] = float(s[int(0.1 * (len(s) - 1))])
        out["strain_half_broken"] = float(s[int(0.5 * (len(s) - 1))])
    return out


def band_share(points, band, d_mean):
    """Fraction of ``points`` [m, 2] [m] within half the band's width (``width_d`` mean diameters
    ``d_mean`` [m]) of the band's centre line (``centre``, unit ``direction``)."""
    if len(points) == 0:
        return 0.0
    c, d = np.asarray(band["centre"], dtype=float), np.asarray(band["direction"], dtype=float)
    r = np.asarray(points, dtype=float) - c
    dist = np.abs(r[:, 0] * d[1] - r[:, 1] * d[0])
    return float(np.mean(dist <= 0.5 * band["width_d"] * d_mean))


# -- localisation ----------------------------------------------------------------------------

def snapshot(sim):
    """The state a window needs (collective; the same on every rank): gid-ordered ``gid``, ``x``
    [n, 2], ``theta`` [n] (spin angle about z [rad]) and the touching contacts ``pair_i``,
    ``pair_j`` (gids)."""
    e, n, c = sim.elements, sim.elements.n_owned, sim.contacts
    cf = contact_forces(sim)
    theta = 2.0 * np.arctan2(e.q[:n, 3], e.q[:n, 0])
    glued = np.zeros(0, np.int64)
    if c.history.shape[1] == hm.WIDTH_CEMENTED:      # the intact cements' ends (each pair once)
        ok = c.counted_once(n) & (c.history[:, hm.CEMENT_STATE] > 0.0)
        glued = np.concatenate([e.gid[c.i[ok]], e.gid[c.j[ok]]])
    parts = sim.comm.allgather((e.gid[:n].copy(), e.x[:n, :2].copy(), theta, cf["gid_i"], cf["gid_j"], glued))
    gid = np.concatenate([p[0] for p in parts])
    o = np.argsort(gid, kind="stable")
    gid = gid[o]
    ends = np.concatenate([p[5] for p in parts]).astype(np.int64)
    return {"gid": gid, "x": np.concatenate([p[1] for p in parts])[o],
            "theta": np.concatenate([p[2] for p in parts])[o],
            "pair_i": np.concatenate([p[3] for p in parts]).astype(np.int64),
            "pair_j": np.concatenate([p[4] for p in parts]).astype(np.int64),
            "cements": np.bincount(np.searchsorted(gid, ends), minlength=len(gid)).astype(np.int64)}


def window_field(ref, cur, platen_gids, d_mean, fraction=0.1):
    """Incremental fields between two snapshots (pure numpy): per grain ``shear``, ``volumetric``,
    ``rotation`` (continuum, [rad]), ``spin`` (the grain's own rotation increment [rad]), and the
    shear band (``shear_band.detect`` on the grains outside the platens) or None, and per grain
    the cements it lost in the window (``cements_broken``; cemented samples)."""
    if not np.array_equal(ref["gid"], cur["gid"]):
        raise ValueError("the grains changed within a localisation window")
    gid = ref["gid"]
    i = np.searchsorted(gid, ref["pair_i"])
    j = np.searchsorted(gid, ref["pair_j"])
    u = cur["x"] - ref["x"]
    G = local_strain.displacement_gradient(len(gid), i, j, ref["x"][j] - ref["x"][i], u[j] - u[i], dim=2)
    m = local_strain.strain_measures(G)
    spin = np.angle(np.exp(1j * (cur["theta"] - ref["theta"])))
    inside = ~np.isin(gid, platen_gids)
    band = None
    try:
        band = shear_band.detect(cur["x"][inside], m["shear"][inside], d_mean, fraction=fraction)
    except ValueError:
        band = None
    broken = np.maximum(ref["cements"] - cur["cements"], 0)
    return {"x": cur["x"], "shear": m["shear"], "volumetric": m["volumetric"], "rotation": m["rotation"],
            "spin": spin, "inside": inside, "band": band, "cements_broken": broken}


__all__ = ["SCHEMA", "STAGES", "COLUMNS", "UNITS", "INT_COLUMNS", "DESCRIPTION", "prepare", "open_sample", "install",
           "start_loading", "sample", "Sampler", "angles", "peak_index", "intact_cements", "CementRecord",
           "cement_damage", "band_share", "snapshot", "window_field", "StepLimit"]
