"""The compression test's deck: its schema and its restart policy (which keys a restart may change)."""
from pardem.io.checkpoint_writer import DECK_SECTION
from pardem.physics import contact_laws
from pardem.config import (Field, auto_or, boolean, choice, fractions_or, number, number_or_triple, optional,
                           positive, restart_differences, strength, triple)

# The compress driver's deck. Defaults are the default case (docs/physics.md section 4: the W study cube).
COMPRESS_SCHEMA = {
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
        "law": Field("TOR", choice("TOR", "hankinson", "linear", "spherical"), "anisotropy law"),
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
        "strain": Field(0.005, number(0.0, 0.5), "nominal strain imposed by the moving plate"),
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
    "checkpoint": dict(DECK_SECTION),
    "output": {
        "series_every": Field(0, optional(number(lo=0, integer=True)),
                              "steps between series samples; 0 = about 200 samples per run"),
        "vtk_every": Field(0, number(lo=0, lo_open=False, integer=True),
                           "steps between ParaView snapshots (DIR/paraview/pardem.pvd); 0 = none"),
    },
}

# Keys a restart may change: the run length and what is written; anything else
# would change the physics of the continued run, and the restart is refused.
RESTART_MAY_CHANGE = {"loading.strain", "run.progress_seconds"}
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
