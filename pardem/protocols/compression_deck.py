"""The compression test's deck: its schema and its restart policy (which keys a restart may change)."""
import math

from pardem.physics.anisotropy import LAWS as ANISOTROPY_LAWS
from pardem.physics import contact_laws
from pardem.physics.timestep import critical_time_step, linear_contact_time_step, rayleigh_time_step
from pardem.config import (DeckError, Field, Schema, auto_or, boolean, choice, fractions_or, number,
                           number_or_triple, positive, restart_differences, strength, triple)
from pardem.protocols import deck_checks as dc
from pardem.protocols import output_deck

COMPACT_MIN_EDGE = 6.0   # pardem.domains.compact.MIN_EDGE: box edges in mean radii a packing needs


def _extremes(v, law=None):
    """(smallest, largest) value a bond can take from a scalar or [L, R, T] deck value: the
    interpolating laws stay within the axis values; W's spherical law reaches sqrt(3) v_max."""
    vals = v if isinstance(v, (tuple, list)) else (v,)
    top = max(vals) * (math.sqrt(3.0) if law == "spherical" else 1.0)
    return min(vals), top


def compress_size_checks(deck):
    """The box holds the domain's elements: at least one diameter per edge (ordered) or six mean
    radii (compact), and ``bond_gap`` > 0 for a compact domain (a gap of 0 bonds only overlapping
    pairs: the bonded cluster falls apart, found only after the packing is built)."""
    dom = deck["domain"]
    box, R = dom["box"], dom["radius"]
    if dom["kind"] == "ordered":
        dc.check_ordered_box(box, R)
        return
    for k, edge in enumerate(box):
        if edge < COMPACT_MIN_EDGE * R:
            raise DeckError(f"domain.box = {list(box)} with domain.radius = {R}: a compact packing needs every "
                            f"box edge at least {COMPACT_MIN_EDGE:g} radii ({dc.fmt(COMPACT_MIN_EDGE * R)} m); "
                            f"domain.box[{k}] = {edge!r} is shorter")
    if dom["bond_gap"] == 0.0:
        raise DeckError("domain.bond_gap = 0.0 with domain.kind = \"compact\": a gap of 0 bonds only the "
                        "overlapping pairs of the packing, which leaves no connected domain; expected a "
                        "number in (0, 0.5]")


def compress_element_counts(deck):
    """Estimated (elements, bonds, contact pairs) of the deck's domain (floats, may be inf)."""
    dom = deck["domain"]
    box, R = dom["box"], dom["radius"]
    if dom["kind"] == "ordered":
        n = dc.ordered_count(box, R)
        bonds = 3.0 * n                 # face neighbours: 3 bonds per element
    else:
        # pardem.domains.compact.element_count: 0.64 of the box in spheres of the mean volume
        mean_volume = 4.0 / 3.0 * math.pi * dc.cube(R) * (1.0 + dom["dispersity"] ** 2)
        n = 0.64 * (box[0] * box[1] * box[2]) / mean_volume
        bonds = 3.5 * n                 # coordination about 7 within the bond gap
    law = deck["contacts"]["law"]
    breakable = _breakable(deck["bonds"])
    pairs = dc.PAIRS_PER_ELEMENT * n if law not in ("none",) and (law != "auto" or breakable) else 0.0
    return n, bonds, pairs


def _breakable(bd):
    def positive_any(v):
        return max(v) > 0.0 if isinstance(v, (tuple, list)) else v > 0.0
    return positive_any(bd["tensile_strength"]) or positive_any(bd["shear_strength"])


def compress_memory_check(deck):
    """The estimated memory of the domain fits the machine (``deck_checks.check_memory``)."""
    n, bonds, pairs = compress_element_counts(deck)
    what = f"{dc.fmt(n)} elements, {dc.fmt(bonds)} bonds" + (f" and {dc.fmt(pairs)} contact pairs" if pairs else "")
    dc.check_memory(n, bonds, pairs, "domain.box, domain.radius", what)


def compress_bond_bounds(deck):
    """Bounds of the bonds' stiffnesses and of the elements' masses, checked to be normal doubles.

    Returns (ka_min, ka_max, m_min, m_max, L0_max): axial stiffness E S / L0 [N/m] of the softest
    and stiffest bond, the lightest and heaviest element [kg], the longest bond [m]."""
    dom, bd = deck["domain"], deck["bonds"]
    R = dom["radius"]
    d = dom["dispersity"] if dom["kind"] == "compact" else 0.0
    r_min, r_max = R * (1.0 - d), R * (1.0 + d)
    gap = dom["bond_gap"] * R if dom["kind"] == "compact" else 0.0
    m_min, m_max = dc.check_sphere(dom["density"], r_min, r_max, "domain.density, domain.radius")
    E_min, E_max = _extremes(bd["young"], bd["law"])
    q_min, q_max = _extremes(bd["radius_ratio"], bd["law"])
    L_min, L_max = 2.0 * r_min, 2.0 * r_max + gap
    keys = "bonds.young, bonds.radius_ratio, domain.radius"
    out = {}
    for which, E, q, L in (("softest", E_min, q_min, L_max), ("stiffest", E_max, q_max, L_min)):
        r = q * R
        S = math.pi * r * r
        inertia = 0.25 * S * r * r
        G = E / (2.0 * (1.0 + bd["poisson"]))
        out[which] = dc.check_normal(E * S / L, f"the {which} bond's axial stiffness E S / L", "N/m", keys)
        dc.check_normal(E * inertia, f"the {which} bond's bending stiffness E I", "N m^2", keys)
        dc.check_normal(G * 2.0 * inertia / L, f"the {which} bond's torsional stiffness G J / L", "N m", keys)
    return out["softest"], out["stiffest"], m_min, m_max, L_max


def compress_time_bounds(deck):
    """Bounds of the deck's run, computed from its values alone (no domain is built).

    * ``dt_critical_max`` [s]: the critical step of the built domain is at most
      ``2 sqrt(m_max / k)`` (``physics.timestep.critical_time_step`` of ``omega^2 = k / m_max``):
      the Gershgorin bound of an element's row holds at least ``k / m`` of each of its bonds and of
      the plates, so the softest bond on the heaviest element, or the deck's plate stiffness,
      bound ``omega^2`` from below; a contact law given in numbers adds its own step (Rayleigh
      step of the largest sphere, linear spring on the heaviest), itself an upper bound.
    * ``dt_max`` [s]: the deck's ``run.dt``, or ``dt_fraction * dt_critical_max``.
    * ``steps_min``: the plate travel ``strain * (box - 2 R_max)`` over ``plate_speed * dt_max``
      (the ramp only lengthens the run; with a ramp longer than the travel, the speed within it
      is below ``v pi^2 t^2 / (4 T^2)``).
    * ``wave_speed_max`` [m/s]: an axial wave runs along the bond chains at ``L0 sqrt(ka / m)``,
      at most ``L0_max sqrt(ka_max / m_min)``.
    """
    dom, ld, run, pl = deck["domain"], deck["loading"], deck["run"], deck["plates"]
    ka_min, ka_max, m_min, m_max, L_max = compress_bond_bounds(deck)
    k = ka_min
    if pl["law"] == "linear" and pl["stiffness"] != "auto":
        k = max(k, pl["stiffness"])
    omega2 = dc.check_normal(k / m_max, "the squared frequency k / m of the softest bond or plate on the "
                             "heaviest element", "1/s^2",
                             "bonds.young, bonds.radius_ratio, plates.stiffness, domain.density, domain.radius")
    dt_up = critical_time_step(omega2)
    R = dom["radius"]
    d = dom["dispersity"] if dom["kind"] == "compact" else 0.0
    ct = deck["contacts"]
    law = ct["law"] if ct["law"] != "auto" else ("hertz_mindlin" if _breakable(deck["bonds"]) else "none")
    if law == "hertz_mindlin" and ct["young"] != "auto":
        G = ct["young"] / (2.0 * (1.0 + ct["poisson"]))
        dt_up = min(dt_up, rayleigh_time_step(R * (1.0 + d), dom["density"], G, ct["poisson"]))
    elif law == "linear" and ct["stiffness"] != "auto":
        dt_up = min(dt_up, linear_contact_time_step(m_max, ct["stiffness"]))
    dt = run["dt"] if run["dt"] != "auto" else run["dt_fraction"] * dt_up
    axis = "xyz".index(ld["axis"])
    length = max(dom["box"][axis] - 2.0 * R * (1.0 + d), 2.0 * R * (1.0 - d))
    travel = ld["strain"] * length
    v = ld["plate_speed"]
    T = ld["ramp_time"] if ld["ramp_time"] != "auto" else 0.0
    if travel >= 0.5 * v * T:
        t_end = travel / v + 0.5 * T
    else:
        t_end = max(travel / v, (12.0 * travel * T * T / (math.pi ** 2 * v)) ** (1.0 / 3.0))
    return {"dt_critical_max": dt_up, "dt_max": dt, "steps_min": t_end / dt,
            "wave_speed_max": L_max * math.sqrt(ka_max / m_min)}


def compress_time_checks(deck):
    """A number ``run.dt`` is below the critical step, the loading takes at most ``MAX_STEPS``
    steps and the plate is slower than the domain's axial waves (``compress_time_bounds``)."""
    ld, run = deck["loading"], deck["run"]
    b = compress_time_bounds(deck)
    dt_up = b["dt_critical_max"]
    if run["dt"] != "auto" and run["dt"] > dt_up:
        raise DeckError(f"run.dt = {run['dt']!r} s is above the critical time step of this deck (at most "
                        f"{dc.fmt(dt_up)} s, from bonds.young, bonds.radius_ratio, plates.stiffness, "
                        f"domain.density, domain.radius): expected a value in (0, {dc.fmt(dt_up)}] or \"auto\"")
    keys = "loading.strain, loading.plate_speed, " + (
        "run.dt" if run["dt"] != "auto" else "the time step (run.dt_fraction of the critical step from "
                                             "bonds.young, bonds.radius_ratio, plates.stiffness, contacts, "
                                             "domain.density, domain.radius)")
    if ld["ramp_time"] != "auto":
        keys += ", loading.ramp_time"
    dc.check_steps(b["steps_min"], keys, "the loading")
    v, c_max = ld["plate_speed"], b["wave_speed_max"]
    if v >= c_max:
        raise DeckError(f"loading.plate_speed = {v!r} m/s is above the domain's axial wave speed (at most "
                        f"{dc.fmt(c_max)} m/s from bonds.young, domain.density, bonds.radius_ratio): the "
                        f"plate would hit the elements faster than they can transmit it; expected a speed "
                        f"below {dc.fmt(c_max)} m/s")


# Run in this order by config.check_deck: sizes before the memory they set, magnitudes before
# the time step and run length computed from them.
COMPRESS_CHECKS = (compress_size_checks, compress_memory_check, compress_time_checks)

# The compress driver's deck. Defaults are the default case (docs/physics.md section 4: the W study cube).
COMPRESS_SCHEMA = Schema({
    "domain": {
        "kind": Field("ordered", choice("ordered", "compact"),
                      "domain builder: ordered (cubic lattice, face bonds) or compact (dense random "
                      "packing, solid fraction >= 0.63, bonds within bond_gap)"),
        "box": Field([0.01, 0.01, 0.01], triple(positive()), "box edge lengths [m]"),
        "radius": Field(0.2381e-3, positive(),
                        "element radius [m]; compact: the requested mean radius (the packing ends "
                        "within about 1 % of it)"),
        "density": Field(1000.0, positive(),
                         "element density rho_e [kg/m^3], used as given for both kinds; the represented "
                         "continuum's density is rho_e times the solid fraction (pi/6 ordered, 0.63-0.64 "
                         "compact), docs/physics.md section 1"),
        "tilt_deg": Field(0.0, number(-90.0, 90.0, lo_open=False, hi_open=False),
                          "tilt of the LRT frame about T (z) [deg]; ordered: the lattice turns with it"),
        "seed": Field(0, number(lo=0, lo_open=False, integer=True),
                      "compact: seed of the random packing (the same seed gives the same packing)"),
        "dispersity": Field(0.1, number(0.0, 0.5, lo_open=False),
                            "compact: radii uniform in radius * (1 - dispersity, 1 + dispersity)"),
        "bond_gap": Field(0.01, number(0.0, 0.5, lo_open=False, hi_open=False),
                          "compact: bond the pairs whose surface gap is below bond_gap * mean radius"),
    },
    "bonds": {
        "young": Field(100e6, number_or_triple(positive()), "bond Young's modulus, or [E_L, E_R, E_T] [Pa]"),
        "law": Field("TOR", choice(*ANISOTROPY_LAWS), "anisotropy law (spherical: the wood study's law as "
                     "printed, not an interpolation; spherical_normalised: its weighted mean)"),
        "radius_ratio": Field(1.0, number_or_triple(positive()),
                              "bond radius / mean element radius, or [r_L, r_R, r_T]"),
        "poisson": Field(0.3, number(-1.0, 0.5), "bond Poisson ratio"),
        "damping": Field(0.2, number(0.0, 1.0, lo_open=False, hi_open=False), "bond damping ratio"),
        "tensile_strength": Field(0.0, strength(),
                                  "bond tensile strength sigma_max = F / S [Pa], or [L, R, T] (all > 0, "
                                  "by the anisotropy law); 0 = unbreakable in tension"),
        "shear_strength": Field(0.0, strength(),
                                "bond shear strength tau_max = |T| / S [Pa], or [L, R, T] (all > 0); "
                                "0 = unbreakable in shear"),
        "densification_stress": Field(0.0, number(lo=0.0, lo_open=False),
                                      "densification threshold sigma0 [Pa] of the bonds initially along "
                                      "T, in compression (docs/physics.md section 7); 0 = elastic"),
        "densification_p0": Field(0.05, positive(),
                                  "densification factor p0: the threshold grows as exp(p / p0) with "
                                  "the plastic strain p"),
    },
    "contacts": {
        "law": Field("auto", choice("auto", "none", *contact_laws.LAWS),
                     "element-element contacts (pairs not joined by an intact bond); auto = "
                     "hertz_mindlin when bonds can break, none otherwise"),
        "young": Field("auto", auto_or(positive()),
                       "hertz_mindlin: Young's modulus of the elements [Pa]; auto = the largest bond modulus"),
        "poisson": Field(0.3, number(-1.0, 0.5), "hertz_mindlin: Poisson ratio of the elements"),
        "stiffness": Field("auto", auto_or(positive()),
                           "linear: kn = kt [N/m]; auto = the mean axial bond stiffness"),
        "friction": Field(0.3, number(lo=0.0, lo_open=False), "Coulomb friction coefficient"),
        "restitution": Field(1.0, number(0.0, 1.0, hi_open=False),
                             "normal restitution coefficient of contacts; 1 = undamped"),
    },
    "plates": {
        "law": Field("linear", choice("linear", "hertz"),
                     "element-wall normal law of the plates and lateral walls"),
        "stiffness": Field("auto", auto_or(positive()),
                           "linear law: element-wall stiffness kn = kt [N/m]; auto = mean axial bond stiffness"),
        "young": Field("auto", auto_or(positive()),
                       "hertz law: Young's modulus of the elements against the rigid walls [Pa]; "
                       "auto = the largest bond modulus"),
        "poisson": Field(0.3, number(-1.0, 0.5), "hertz law: Poisson ratio of the elements"),
        "friction": Field(0.0, number(lo=0.0, lo_open=False),
                          "Coulomb friction coefficient of the walls; 0 = frictionless (no history)"),
        "restitution": Field(1.0, number(0.0, 1.0, hi_open=False),
                             "normal restitution coefficient of element-wall impacts; 1 = undamped"),
        "lateral_walls": Field(False, boolean,
                               "fixed walls on the four faces across the load (at the outer element "
                               "surfaces): a laterally confined test"),
    },
    "loading": {
        "axis": Field("x", choice("x", "y", "z"), "loading axis"),
        "strain": Field(0.005, number(dc.MIN_STRAIN, 0.5, lo_open=False),
                        "nominal strain imposed by the moving plate (at least 1e-12: positions carry a "
                        "relative round-off of 1e-16)"),
        "plate_speed": Field(0.5, positive(), "moving plate speed [m/s]"),
        "ramp_time": Field("auto", auto_or(number(lo=0.0, lo_open=False)),
                           "time [s] over which the plate speed rises smoothly from 0; auto = 4 L / c "
                           "(two periods of the slowest axial mode, c from the bonds along the "
                           "axis), at most the time to cover half the travel"),
    },
    "run": {
        "dt": Field("auto", auto_or(positive()), "time step [s], or auto = dt_fraction * critical step"),
        "dt_fraction": Field(0.5, number(0.0, 1.0, hi_open=False), "fraction of the critical step when dt = auto"),
        "progress_seconds": Field(5.0, positive(), "seconds between progress lines (rank 0)"),
        "watchdog_seconds": dc.WATCHDOG_FIELD,
        "skin": Field("auto", auto_or(positive()),
                      "Verlet skin [m]: displacement budget between ghost and contact list rebuilds; "
                      "auto = 0.2 R"),
    },
    "parallel": {
        "slab_axis": Field("auto", choice("auto", "x", "y", "z"),
                           "axis the slabs are stacked along; auto = longest extent, not the loading axis"),
        "balance_every": Field(200, number(lo=0, lo_open=False, integer=True),
                               "steps between load-balance checks; 0 = never"),
        "balance_threshold": Field(0.05, number(0.0, 1.0), "re-cut slabs when per-rank loads differ by more (max/min - 1)"),
        "balance_by": Field("count", choice("count", "time"), "load measure: owned elements or computing seconds"),
        "initial_split": Field("balanced", fractions_or("balanced"),
                               "initial cuts: balanced, or cumulative element fractions (one per cut)"),
    },
    "checkpoint": dict(output_deck.CHECKPOINT_SECTION),
    "output": output_deck.output_section(series_every=output_deck.series_every()),
}, checks=COMPRESS_CHECKS)

# Keys a restart may change: the run length and what is written; anything else
# would change the physics of the continued run, and the restart is refused.
RESTART_MAY_CHANGE = {"loading.strain", "run.progress_seconds", "run.watchdog_seconds"}
RESTART_MAY_CHANGE_SECTIONS = {"output", "checkpoint", "parallel"}


def physics_differences(old, new):
    """Keys (``section.key``, old, new) whose values differ between two checked compression decks
    and may not on restart."""
    return restart_differences(COMPRESS_SCHEMA, old, new, RESTART_MAY_CHANGE, RESTART_MAY_CHANGE_SECTIONS)


def upgrade(raw):
    """A deck stored by an earlier version (a checkpoint's) in today's layout: ``parallel.skin``
    moved to ``run.skin``. Returns a new dict; today's decks come back unchanged."""
    raw = {k: dict(v) if isinstance(v, dict) else v for k, v in raw.items()}
    par = raw.get("parallel", {})
    if isinstance(par, dict) and "skin" in par:
        raw.setdefault("run", {})["skin"] = par.pop("skin")
    return raw
