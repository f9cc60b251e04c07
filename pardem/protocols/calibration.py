"""Calibration of the beam bonds from target domain properties. docs/physics.md sections 1 and 6.

Pure arithmetic (no MPI, no files): target moduli, density and strengths of the represented
continuum in, bond parameters of the ordered cubic lattice out. Per direction k in (L, R, T), with
``E_k^D`` the target Young's modulus along k and ``G^D`` the target shear modulus [Pa]::

    E_k^mu r_k^2 = (4/pi) E_k^D                (axial: exact for the lattice)
    E_k^mu r_k^4 = c_G G^D                     (shear)
    =>  r_k^2 = (pi/4) c_G G^D / E_k^D,   E_k^mu = (4/pi) E_k^D / r_k^2
    sigma_k^mu = 4 / (pi r_k^2) * sigma_k^D    (every stress threshold: tension, shear, densification)
    rho_e = (6/pi) rho_D                       (element density, ordered lattice of touching spheres)

Two shear relations (``RELATIONS``, chosen by the deck's ``bonds.relations``):

* ``"section6"``: W's relation, ``c_G = 16/(3 pi)``. It holds both elements of a bond without
  rotation, and it reproduces W's published bond set; the face-bonded lattice built with it has
  half the target shear modulus.
* ``"exact"``: the face-bonded lattice's own relation, ``c_G = 32/(3 pi)``. In a uniform shear of
  the plane (a, b) (engineering strain gamma) the elements rotate freely; minimising the bending
  energy of the bonds along a and along b over that rotation gives (``beta = E I``, spacing
  ``l = 2R``, one bond of each direction per ``l^3``)::

      G_ab = (3 pi / 32) * 2 x y / (x + y),   x = E_a^mu r_a^4,  y = E_b^mu r_b^4

  (``lattice_shear_modulus``), so ``E_k^mu r_k^4 = 32/(3 pi) G^D`` in every direction makes
  ``G_ab = G^D`` in all three planes.

The lattice has Poisson ratio 0 whatever the relations (``LATTICE_POISSON``): face bonds along the
load carry it alone and nothing couples it to the lateral directions (docs/physics.md section 4).

Compact (random) domains have no closed form: with ``domain.kind = "compact"`` the driver calibrates
them by measurement (``pardem.protocols.compact_calibration``, deck section ``[compact]``), starting
from these relations.

References: docs/physics.md sections 1, 2, 4, 6 (W 4.5, 4.14).
"""
import math
from dataclasses import asdict, dataclass

from pardem.physics.anisotropy import LAWS as ANISOTROPY_LAWS
from pardem.config import DeckError, Field, Schema, boolean, choice, number, positive, same_or, strength, triple
from pardem.protocols import deck_checks, output_deck

DIRECTIONS = "LRT"
R_MAX = 2.0            # largest adimensional bond radius accepted (W's calibrated set has 1.14)
SHEAR_PLANES = {"LR": (0, 1), "LT": (0, 2), "RT": (1, 2)}   # (shear direction a, gradient axis b)
AXES = {"L": "x", "R": "y", "T": "z"}      # the verification lattice is untilted
# E^mu r^4 = SHEAR_FACTOR[relations] G^D (module docstring)
SHEAR_FACTOR = {"exact": 32.0 / (3.0 * math.pi), "section6": 16.0 / (3.0 * math.pi)}
RELATIONS = tuple(SHEAR_FACTOR)
LATTICE_POISSON = 0.0
POISSON_NOTE = ("Poisson ratio 0: the face-bonded ordered lattice loaded along a lattice axis has no lateral "
                "strain (face bonds along the load carry it alone); compact (random) domains, and lattices "
                "loaded off their axes, have a non-zero one (docs/physics.md section 4)")


# The targets deck of ``python -m pardem.drivers.calibrate`` (see drivers/calibrate_beech.toml).
CALIBRATE_SCHEMA = {
    "targets": {
        "young_L": Field(9.47e9, positive(), "E_L^D, domain Young's modulus along L [Pa]"),
        "young_R": Field("same", same_or(positive()),
                         "E_R^D along R [Pa]; \"same\" = E_T^D (then E_R^mu = E_T^mu, r_R = r_T)"),
        "young_T": Field(7.89e8, positive(), "E_T^D, domain Young's modulus along T [Pa]"),
        "shear": Field(7.7e8, positive(),
                       f"G^D, domain shear modulus [Pa]; r_k = sqrt(c G^D / E_k^D) must be <= {R_MAX:g} "
                       f"(c = 8/3 exact, 4/3 section6)"),
        "density": Field(720.0, positive(), "rho_D, density of the represented continuum [kg/m^3]"),
        "tensile_strength": Field(0.0, strength(),
                                  "sigma_max^D, tensile strength [Pa] (scalar or [L, R, T]); 0 = unbreakable"),
        "shear_strength": Field(0.0, strength(),
                                "tau_max^D, shear strength [Pa] (scalar or [L, R, T]); 0 = unbreakable"),
        "densification_stress": Field(0.0, number(lo=0.0, lo_open=False),
                                      "sigma0^D, densification threshold in compression along T [Pa]; "
                                      "0 = elastic"),
        "densification_p0": Field(0.05, positive(), "p0 of docs/physics.md section 7 (dimensionless, not scaled)"),
    },
    "domain": {
        "box": Field([0.01, 0.01, 0.01], triple(positive()), "box of the calibrated deck's ordered domain [m]"),
        "radius": Field(0.2381e-3, positive(), "element radius [m] (compact: the requested mean radius)"),
        "kind": Field("ordered", choice("ordered", "compact"),
                      "domain to calibrate: ordered (closed-form relations, --verify measures them) or compact "
                      "(random packing: iterative calibration by measurement, section [compact])"),
        "dispersity": Field(0.1, number(0.0, 0.5, lo_open=False),
                            "compact: radii uniform in radius * (1 - dispersity, 1 + dispersity)"),
        "bond_gap": Field(0.01, number(0.0, 0.5, lo_open=True, hi_open=False),
                          "compact: bond the pairs whose surface gap is below bond_gap * mean radius"),
        "seed": Field(0, number(lo=0, lo_open=False, integer=True),
                      "compact: packing seed of realisation 0 (realisation k uses seed + k)"),
    },
    "bonds": {
        "relations": Field("exact", choice(*RELATIONS),
                           "shear relation of the calibration: exact (the face-bonded lattice's: its G equals "
                           "G^D) or section6 (W's, rotation-blocked bonds: reproduces W's bond set, the "
                           "lattice's G is G^D/2)"),
        "law": Field("TOR", choice(*ANISOTROPY_LAWS),
                     "anisotropy law of the calibrated deck (TOR: the ordered lattice's bonds lie along L, R, T)"),
        "poisson": Field(0.3, number(-1.0, 0.5), "bond Poisson ratio (torsion only)"),
        "damping": Field(0.2, number(0.0, 1.0, lo_open=False, hi_open=False), "bond damping ratio"),
    },
    "verify": {
        "strain": Field(0.002, number(0.0, 0.05), "--verify: nominal compression strain along L, R and T"),
        "shear_strain": Field(0.002, number(0.0, 0.05), "--verify: engineering shear strain of the shear tests"),
        "shear_plane": Field("all", choice("all", *SHEAR_PLANES),
                             "--verify: plane of the shear test, or all (LR, LT and RT)"),
        "transits": Field(8.0, number(1.0, 1000.0, lo_open=False, hi_open=False),
                          "--verify: loading time in wave transits across the domain"),
        "quick_elements": Field(8, number(lo=4, lo_open=False, hi=40, hi_open=False, integer=True),
                                "--quick: elements per edge of the verification cube"),
        "shear": Field(True, boolean, "--verify: run the shear tests too"),
        "tolerance": Field(0.02, number(0.0, 1.0),
                           "--verify: largest |measured / target - 1| of a modulus that passes"),
    },
    "compact": {
        "realisations": Field(4, number(lo=1, lo_open=False, hi=256, hi_open=False, integer=True),
                              "compact: packings (seeds domain.seed + k) whose mean moduli are calibrated; "
                              "spread over the ranks, one realisation per rank at a time"),
        "shear_plane": Field("LT", choice(*SHEAR_PLANES, "all"),
                             "compact: plane whose shear modulus must equal targets.shear (one common bond "
                             "radius factor is fitted), or all (G_LR = G_LT = G_RT = targets.shear: one radius "
                             "per direction)"),
        "tolerance": Field(0.02, number(0.0, 0.5),
                           "compact: largest |mean measured / target - 1| of every modulus at convergence"),
        "max_iterations": Field(8, number(lo=1, lo_open=False, hi=50, hi_open=False, integer=True),
                                "compact: measurements at most (exit code 6 when the last misses a target)"),
        "max_step": Field(4.0, number(1.0, 100.0, hi_open=False),
                          "compact: largest factor by which one iteration changes a bond modulus or radius"),
        "start_factors": Field([1.0, 1.0, 1.0], triple(number(0.01, 100.0, lo_open=False, hi_open=False)),
                               "compact: first bond moduli (L, R, T) = these factors times the closed form of "
                               "bonds.relations"),
        "start_radius_factor": Field(1.0, number(0.1, 10.0, lo_open=False, hi_open=False),
                                     "compact: first bond radius ratios = this factor times the closed form"),
        "strain": Field(0.002, number(0.0, 0.05), "compact: nominal compression strain of the measurements"),
        "shear_strain": Field(0.002, number(0.0, 0.05), "compact: engineering shear strain of the shear tests"),
        "transits": Field(6.0, number(1.0, 1000.0, lo_open=False, hi_open=False),
                          "compact: loading time of every test in wave transits across the domain"),
    },
    "output": output_deck.output_section(
        series_every=output_deck.series_every("--verify: steps between series samples of a run; 0 = about 200 "
                                              "per run", zero=0),
        vtk=output_deck.vtk_every("DIR/paraview/<run>/pardem.pvd", when="--verify: ")),
}
COMPACT_MIN_EDGE = 6.0       # pardem.domains.compact.MIN_EDGE (mean radii per box edge)


def compact_checks(deck):
    """A compact calibration's box holds a packing (every edge at least COMPACT_MIN_EDGE radii) and
    its strains can be resolved (``deck_checks.check_strain``)."""
    if deck["domain"]["kind"] != "compact":
        return
    box, R = deck["domain"]["box"], deck["domain"]["radius"]
    for k, edge in enumerate(box):
        if edge < COMPACT_MIN_EDGE * R:
            raise DeckError(f"domain.box = {list(box)} with domain.radius = {R}: domain.box[{k}] = {edge!r} is "
                            f"too short for a compact packing: expected every edge at least {COMPACT_MIN_EDGE:g} "
                            f"radii ({COMPACT_MIN_EDGE * R:.6g} m)")
    for key in ("strain", "shear_strain"):
        deck_checks.check_strain(deck["compact"][key], f"compact.{key}")


CALIBRATE_SCHEMA = Schema(CALIBRATE_SCHEMA, checks=deck_checks.CALIBRATE_CHECKS + (compact_checks,))


@dataclass(frozen=True)
class Targets:
    """Properties of the represented continuum (SI): moduli [Pa] (young_R None = same as young_T),
    density [kg/m^3], strengths [Pa] as (L, R, T), densification threshold [Pa] along T, p0 [-]."""
    young_L: float
    young_T: float
    shear: float
    density: float
    young_R: float = None
    tensile_strength: tuple = (0.0, 0.0, 0.0)
    shear_strength: tuple = (0.0, 0.0, 0.0)
    densification_stress: float = 0.0
    densification_p0: float = 0.05

    @classmethod
    def from_deck(cls, deck):
        """From the checked ``[targets]`` section of CALIBRATE_SCHEMA."""
        t = deck["targets"]
        return cls(young_L=t["young_L"], young_T=t["young_T"], shear=t["shear"], density=t["density"],
                   young_R=None if t["young_R"] == "same" else t["young_R"],
                   tensile_strength=as_lrt(t["tensile_strength"]), shear_strength=as_lrt(t["shear_strength"]),
                   densification_stress=t["densification_stress"], densification_p0=t["densification_p0"])

    def young(self):
        """(E_L^D, E_R^D, E_T^D) [Pa]."""
        return (self.young_L, self.young_T if self.young_R is None else self.young_R, self.young_T)


@dataclass(frozen=True)
class BondCalibration:
    """Bond parameters from ``calibrate`` (each (L, R, T) triple in that order).

    young [Pa], radius_ratio [-], tensile_strength and shear_strength [Pa] (0 = none),
    densification_stress [Pa] (bonds along T), densification_p0 [-], element_density [kg/m^3].
    """
    young: tuple
    radius_ratio: tuple
    tensile_strength: tuple
    shear_strength: tuple
    densification_stress: float
    densification_p0: float
    element_density: float

    def as_dict(self):
        return asdict(self)


def as_lrt(v):
    """(L, R, T) floats of a scalar or a triple."""
    return tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else (float(v),) * 3


def check_targets(t, relations="exact"):
    """Raise DeckError naming the first unusable target field and its allowed range."""
    for name in ("young_L", "young_T", "shear", "density"):
        v = getattr(t, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise DeckError(f"targets.{name} = {v!r}: expected a number in (0, inf)")
    if t.young_R is not None and not (math.isfinite(t.young_R) and t.young_R > 0):
        raise DeckError(f"targets.young_R = {t.young_R!r}: expected a number in (0, inf) or \"same\"")
    E = t.young()
    c = radius_factor(relations)
    limit = R_MAX**2 * min(E) / c
    if t.shear > limit:
        k = DIRECTIONS[E.index(min(E))]
        raise DeckError(f"targets.shear = {t.shear!r} is out of range: expected a number in (0, {limit:.6g}] "
                        f"(r_max^2 E_{k}^D / {c:.4g} with r_max = {R_MAX:g}, bonds.relations = {relations}: the "
                        f"bond radius ratio r_{k} = sqrt({c:.4g} G^D / E_{k}^D) would exceed {R_MAX:g})")
    for name in ("tensile_strength", "shear_strength"):
        vals = getattr(t, name)
        if len(vals) != 3 or any(not (math.isfinite(x) and x >= 0) for x in vals) or (
                min(vals) == 0.0 < max(vals)):
            raise DeckError(f"targets.{name} = {list(vals)!r}: expected a number >= 0 or 3 numbers > 0 (L, R, T)")
    if not (math.isfinite(t.densification_stress) and t.densification_stress >= 0):
        raise DeckError(f"targets.densification_stress = {t.densification_stress!r}: expected a number in [0, inf)")
    if not (math.isfinite(t.densification_p0) and t.densification_p0 > 0):
        raise DeckError(f"targets.densification_p0 = {t.densification_p0!r}: expected a number in (0, inf)")


def radius_factor(relations):
    """``c`` of ``r_k^2 = c G^D / E_k^D``: (pi/4) SHEAR_FACTOR, 8/3 (exact) or 4/3 (section6)."""
    if relations not in SHEAR_FACTOR:
        raise ValueError(f"relations {relations!r}: expected one of {', '.join(RELATIONS)}")
    return math.pi / 4.0 * SHEAR_FACTOR[relations]


def calibrate(targets, relations="exact"):
    """Bond parameters of the ordered lattice reproducing ``targets`` (docs/physics.md section 6) by
    the shear relation ``relations`` ("exact" or "section6", module docstring).

    Returns a ``BondCalibration``; DeckError on unusable targets.
    """
    check_targets(targets, relations)
    E_D = targets.young()
    r2 = tuple(radius_factor(relations) * targets.shear / e for e in E_D)
    young = tuple(4.0 / math.pi * e / s for e, s in zip(E_D, r2))
    scale = tuple(4.0 / (math.pi * s) for s in r2)            # sigma^mu / sigma^D per direction
    return BondCalibration(
        young=young, radius_ratio=tuple(math.sqrt(s) for s in r2),
        tensile_strength=tuple(c * s for c, s in zip(scale, targets.tensile_strength)),
        shear_strength=tuple(c * s for c, s in zip(scale, targets.shear_strength)),
        densification_stress=scale[2] * targets.densification_stress,
        densification_p0=targets.densification_p0,
        element_density=6.0 / math.pi * targets.density)


def lattice_young(young, radius_ratio):
    """Domain modulus ``(pi/4) E^mu r^2`` [Pa] of the ordered lattice along a lattice axis whose bonds
    have modulus ``young`` [Pa] and radius ratio ``radius_ratio`` (docs/physics.md section 6)."""
    return math.pi / 4.0 * young * radius_ratio**2


def section6_shear_modulus(young, radius_ratio):
    """The shear modulus section 6 ascribes to bonds ``(E^mu, r)``: ``(3 pi / 16) E^mu r^4`` [Pa]."""
    return 3.0 * math.pi / 16.0 * young * radius_ratio**4


def lattice_shear_modulus(young, radius_ratio, plane):
    """Beam-theory shear modulus [Pa] of the face-bonded cubic lattice in ``plane`` ("LR", "LT", "RT").

    ``young`` and ``radius_ratio`` are (L, R, T) triples of the bonds. ``(3 pi / 32)`` times the
    harmonic mean of ``E^mu r^4`` over the two directions of the plane (module docstring).
    """
    a, b = SHEAR_PLANES[plane]
    x = young[a] * radius_ratio[a] ** 4
    y = young[b] * radius_ratio[b] ** 4
    return 3.0 * math.pi / 32.0 * 2.0 * x * y / (x + y)


def predictions(cal):
    """Analytic domain properties [Pa] of the lattice of the bonds ``cal``: ``young_L``, ``young_R``,
    ``young_T`` (``lattice_young``, exact for the lattice), per plane P in LR, LT, RT
    ``shear_P`` (the lattice's, ``lattice_shear_modulus``) and ``shear_P_section6`` (what W's
    rotation-blocked relation ascribes to the same bonds: twice the lattice's), and ``poisson``
    (the lattice's Poisson ratios, 0)."""
    E = [lattice_young(e, r) for e, r in zip(cal.young, cal.radius_ratio)]
    out = {"young_L": E[0], "young_R": E[1], "young_T": E[2]}
    for plane in SHEAR_PLANES:
        G = lattice_shear_modulus(cal.young, cal.radius_ratio, plane)
        out[f"shear_{plane}"] = G
        out[f"shear_{plane}_section6"] = 2.0 * G
    out["poisson"] = LATTICE_POISSON
    return out


def compress_deck(cal, deck, strengths_known=True):
    """The raw (TOML-ready) compress deck of the calibration ``cal`` and the targets ``deck``.

    ``strengths_known``: the compress schema has the rupture and densification keys; otherwise they
    are left out (and the caller should say so).
    """
    def triple_or_scalar(v):
        return list(v) if len(set(v)) > 1 else v[0]
    bonds = {"young": list(cal.young), "law": deck["bonds"]["law"], "radius_ratio": list(cal.radius_ratio),
             "poisson": deck["bonds"]["poisson"], "damping": deck["bonds"]["damping"]}
    if strengths_known:
        bonds.update(tensile_strength=triple_or_scalar(cal.tensile_strength),
                     shear_strength=triple_or_scalar(cal.shear_strength),
                     densification_stress=cal.densification_stress, densification_p0=cal.densification_p0)
    return {"domain": {"kind": "ordered", "box": list(deck["domain"]["box"]), "radius": deck["domain"]["radius"],
                       "density": cal.element_density, "tilt_deg": 0.0},
            "bonds": bonds}
