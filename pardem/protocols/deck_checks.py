"""Cross-field deck checks: what the drivers' schemas share (memory and run-length estimates,
derived magnitudes) and the checks of the calibrate deck.

Every check takes a deck whose fields passed their own checkers and raises ``DeckError`` with one
line naming the keys that set the refused quantity; it runs inside ``config.check_deck`` (a
``config.Schema``'s ``checks``), before anything is allocated or written. The estimates are made
so that a deck is refused only when the run certainly cannot work: element counts and critical
steps are bounds taken on the safe side (see each function).
"""
import math
import sys

from pardem.config import DeckError, Field, _short, number
from pardem.io.machine import available_memory

# The watchdog (pardem.parallel.watchdog) checks every rank once per period of min(1 s, limit / 10)
# and gives a rank falling silent a grace of max(3 periods, 2 s) before judging it (a compiled call
# or a checkpoint write may hold the thread that long). A limit must span several of those rounds,
# or a healthy run is aborted: 10 s is ten periods of 1 s and five times the grace.
WATCHDOG_MIN_SECONDS = 10.0


def _watchdog_seconds(name, v):
    """0 (off) or a limit of at least ``WATCHDOG_MIN_SECONDS`` [s]."""
    inner = number(lo=WATCHDOG_MIN_SECONDS, lo_open=False)
    if not isinstance(v, bool) and isinstance(v, (int, float)) and v == 0:
        return 0.0
    try:
        return inner(name, v)
    except DeckError:
        raise DeckError(f"{name} = {_short(v)}: expected 0 (off) or a number of seconds >= "
                        f"{WATCHDOG_MIN_SECONDS:g} (the watchdog checks once a second and allows a rank 2 s "
                        f"of silence before judging it: a shorter limit aborts healthy runs)") from None


_watchdog_seconds.inner = number(lo=WATCHDOG_MIN_SECONDS, lo_open=False)

# [run] watchdog_seconds of every driver's deck (read by ``pardem.drivers.cli.read_deck``)
WATCHDOG_FIELD = Field(120.0, _watchdog_seconds,
                       f"abort the job when a rank shows no progress for this long [s] (0 = off, else >= "
                       f"{WATCHDOG_MIN_SECONDS:g})")

# The grains' elastic moduli: no solid is stiffer than diamond (Young's modulus about 1.1e12 Pa,
# shear modulus about 0.5e12 Pa); ten times that bounds every material a deck may describe and
# keeps every derived stiffness (E = 2 G (1 + nu), contact stiffnesses, wave speeds) finite.
MAX_MODULUS = 1e13
# A confining or preparation pressure p of Hertzian grains of Young's modulus E: a dense packing
# (solid fraction 0.64, coordination 6) carries a mean contact force F = 4 pi R^2 p / (0.64 x 6)
# and Hertz's law gives the overlap delta / R = (3 F / (4 E* sqrt(R / 2) R^1.5))^(2/3) with
# E* = E / (2 (1 - nu^2)): about 3.5 % at p = E / 1000, 16 % at p = E / 100. Hertz's law is a small-
# strain result (delta << R) and the grains' elasticity fails well before, so p <= E / 100 bounds
# every meaningful test (the shipped decks stay below E / 500).
MAX_PRESSURE_FRACTION = 0.01


def modulus():
    """Checker of a grain modulus [Pa]: in (0, ``MAX_MODULUS``]."""
    return number(lo=0.0, hi=MAX_MODULUS, hi_open=False)


def tolerance():
    """Checker of a relative tolerance: in (0, 1] (above 1 a criterion is off)."""
    return number(lo=0.0, hi=1.0, hi_open=False)


def check_pressures(pressures, young, key, modulus_keys):
    """Refuse a pressure [Pa] above ``MAX_PRESSURE_FRACTION`` of the grains' Young modulus ``young``
    [Pa] (set by ``modulus_keys``): Hertzian grains would overlap by more than 15 % of their radius."""
    limit = MAX_PRESSURE_FRACTION * young
    for k, p in enumerate(pressures):
        if not p <= limit:
            where = key if len(pressures) == 1 and not key.endswith("s") else f"{key}[{k}]"
            raise DeckError(f"{where} = {p!r} Pa is above {MAX_PRESSURE_FRACTION:g} x the grains' Young modulus "
                            f"{fmt(young)} Pa ({modulus_keys}): Hertzian grains would overlap by more than 15 % "
                            f"of their radius; expected a pressure of at most {fmt(limit)} Pa")

MAX_STEPS = 1e10        # a longer run is refused (about a year at 300 steps/s)
MIN_STRAIN = 1e-12      # positions carry a relative round-off of 1e-16: a strain of 1e-12 keeps 4 digits
DOUBLE_MIN = sys.float_info.min
DOUBLE_MAX = sys.float_info.max
PAIRS_PER_ELEMENT = 6.0   # contact-list pairs per element, each counted once: a jammed packing's
#                           coordination is about 6 (3 pairs per element), the Verlet list within
#                           the skin adds up to half as many again; 6 bounds both


def _bytes_per_element_and_bond():
    """Bytes of one element's and one bond's state arrays, from the engine's own classes (two
    walls' history per element: the plates)."""
    import numpy as np
    from pardem.engine.state import Bonds, Elements
    e = Elements.from_spheres(np.zeros((1, 3)), 1.0, 1.0)
    b = Bonds.empty()
    per_bond = sum(v.itemsize * int(np.prod(v.shape[1:])) for v in vars(b).values()
                   if isinstance(v, np.ndarray))
    return e.nbytes() + 2 * 3 * 8, per_bond


_SIZES = None


def state_bytes():
    """(bytes per element, bytes per bond, bytes per contact pair) of the run's state."""
    global _SIZES
    if _SIZES is None:
        el, bond = _bytes_per_element_and_bond()
        # contact pair: i, j (int32), key (int64), shift (3 int8), a history of up to 8 doubles,
        # and the Verlet list's candidate (i, j)
        _SIZES = (el, bond, 8 + 8 + 3 + 8 * 8 + 8)
    return _SIZES


# Global arrays every rank builds before keeping its slab (lattice or gas centres, candidate
# indices, pair lists, sort keys), on top of the state: tracemalloc's peak over build_case of
# ordered lattices of 1,728 to 35,937 elements is 1,710-1,780 bytes per element, 345 + 3 x 233 of
# them the state (tests/test_fuzz_decks.py checks the estimate against it).
BUILD_BYTES_PER_ELEMENT = 1000


def fmt(x):
    """A number for a message: 4 significant digits, inf as 'inf'."""
    return f"{x:.4g}"


def gib(n_bytes):
    return f"{n_bytes / 2**30:.3g} GiB"


def estimate_memory(n_elements, n_bonds=0.0, n_pairs=0.0):
    """Estimated bytes of a run of ``n_elements`` elements (floats: may be inf), ``n_bonds`` bonds
    and ``n_pairs`` contact pairs: the state plus the global arrays of the build."""
    el, bond, pair = state_bytes()
    return n_elements * (el + BUILD_BYTES_PER_ELEMENT) + n_bonds * bond + n_pairs * pair


_ranks_per_node = 1     # ranks of the job sharing this node's memory (``set_ranks_per_node``)


def set_ranks_per_node(ranks):
    """The number of ranks of the job on this rank's node (``pardem.parallel.layout``; the drivers
    set it before checking a deck): each of them builds the whole case before keeping its slab."""
    global _ranks_per_node
    _ranks_per_node = max(1, int(ranks))


def check_memory(n_elements, n_bonds, n_pairs, keys, what):
    """Refuse a run whose estimated memory on this node exceeds the memory available on it: every
    rank on the node builds the whole case (global arrays and state) before it keeps its slab, so
    the node's peak is the ranks on it times one build.

    ``keys``: the deck keys that set the size (named in the message); ``what``: the counts in words.
    Returns the estimate of one rank [bytes]."""
    need = estimate_memory(n_elements, n_bonds, n_pairs)
    node = need * _ranks_per_node
    have = available_memory()
    if not math.isfinite(node) or (have is not None and node > have):
        avail = f"the {gib(have)} available on this machine" if have is not None else "any machine's memory"
        per = (f"; {_ranks_per_node} ranks on this node each build the whole case, {gib(need)} each"
               if _ranks_per_node > 1 else "")
        raise DeckError(f"{keys}: {what} need about {gib(node)} of memory{per}, more than {avail}: expected a "
                        f"smaller domain (fewer elements)" + (" or fewer ranks per node" if _ranks_per_node > 1 else ""))
    return need


def check_steps(steps, keys, what="the run"):
    """Refuse a run of more than MAX_STEPS steps (``steps`` may be inf)."""
    if not steps <= MAX_STEPS:
        raise DeckError(f"{keys}: {what} would take {fmt(steps)} steps, more than {MAX_STEPS:.0e}: expected "
                        f"values giving a run of at most {MAX_STEPS:.0e} steps")


def check_normal(value, label, unit, keys):
    """Refuse a derived quantity that is not a positive normal double (0, subnormal, inf, nan)."""
    if not (DOUBLE_MIN <= value <= DOUBLE_MAX):
        raise DeckError(f"{keys}: {label} = {fmt(value)} {unit} is outside double precision "
                        f"([{DOUBLE_MIN:.3g}, {DOUBLE_MAX:.3g}]): expected physically meaningful magnitudes")
    return value


def check_strain(value, key):
    """A strain below MIN_STRAIN cannot be resolved over a domain in double precision."""
    if value < MIN_STRAIN:
        raise DeckError(f"{key} = {value!r} is below {MIN_STRAIN:g}: positions carry a relative round-off "
                        f"of 1e-16, so such a strain cannot be resolved; expected a number in "
                        f"[{MIN_STRAIN:g}, ...)")


def cube(x):
    """``x**3`` without OverflowError (inf instead)."""
    return x * x * x


def sphere_mass(density, radius):
    return density * 4.0 / 3.0 * math.pi * cube(radius)


def check_sphere(density, r_min, r_max, keys):
    """The smallest and largest spheres' mass and moment of inertia are normal doubles, and so are
    their inverses (the integrator divides by them). Returns (m_min, m_max) [kg]."""
    m_min, m_max = sphere_mass(density, r_min), sphere_mass(density, r_max)
    for m, r, which in ((m_min, r_min, "smallest"), (m_max, r_max, "largest")):
        check_normal(m, f"the {which} element's mass", "kg", keys)
        check_normal(0.4 * m * r * r, f"the {which} element's moment of inertia", "kg m^2", keys)
    return m_min, m_max


def ordered_count(box, radius):
    """Elements of the ordered lattice in ``box`` [m] (float, may be inf): box volume over the
    (2R)^3 of one site. Exact for an untilted box of whole diameters; a tilted lattice keeps
    about as many."""
    d = 2.0 * radius
    return (box[0] / d) * (box[1] / d) * (box[2] / d)


def check_ordered_box(box, radius, box_key="domain.box", radius_key="domain.radius"):
    """Every edge holds at least one element diameter (the lattice's floor(L / 2R) >= 1)."""
    for k, edge in enumerate(box):
        if edge < 2.0 * radius * (1.0 - 1e-6):
            raise DeckError(f"{box_key}[{k}] = {edge!r} with {radius_key} = {radius!r}: the edge is "
                            f"smaller than one element diameter ({fmt(2.0 * radius)} m); expected "
                            f"edges of at least 2 {radius_key}")


# -- the calibrate deck (pardem.protocols.calibration.CALIBRATE_SCHEMA) ----------------------------

def calibrate_checks(deck):
    """Cross-field checks of a calibrate deck: the ordered domain of ``[domain]`` fits the
    machine, its elements' mass is representable, the verification strains can be resolved.
    (The calibrated compress deck is checked again by the compress schema's checks.)"""
    box, R = deck["domain"]["box"], deck["domain"]["radius"]
    keys = "domain.box, domain.radius"
    check_ordered_box(box, R)
    check_sphere(deck["targets"]["density"], R, R, "targets.density, domain.radius")
    n = ordered_count(box, R)
    check_memory(n, 3.0 * n, 0.0, keys, f"{fmt(n)} elements and {fmt(3.0 * n)} bonds")
    v = deck.get("verify", {})
    for key in ("strain", "shear_strain"):
        if key in v:
            check_strain(v[key], f"verify.{key}")


CALIBRATE_CHECKS = (calibrate_checks,)

# The anisotropy study's decks are compress decks (COMPRESS_SCHEMA, its base deck STUDY_DECK):
# the compress schema's checks already run on them and on every case deck (case_deck calls
# check_deck(COMPRESS_SCHEMA, ...)); the study adds no key of its own to check.
ANISOTROPY_CHECKS = ()


def check_rate(rate, edge, speed, key, speed_keys):
    """Refuse a cell strain rate ``rate`` [1/s] that moves an edge of ``edge`` [m] at or above the
    grains' wave speed ``speed`` [m/s]: the boundary would outrun the contacts (an impact, not a
    test). ``edge`` is taken at the densest packing (the smallest cell), so only such decks are
    refused."""
    if rate * edge >= speed:
        raise DeckError(f"{key} = {rate!r} 1/s moves the cell's edge of about {fmt(edge)} m at "
                        f"{fmt(rate * edge)} m/s, above the grains' wave speed sqrt(E / rho) = {fmt(speed)} m/s "
                        f"({speed_keys}): expected a rate below {fmt(speed / edge)} 1/s")


def check_drag(damping, dt, key):
    """Refuse a global viscous damping C [1/s] with C dt >= 1: the drag -C m v would remove more
    than the whole velocity in one step (explicit drag is stable only for C dt < 2)."""
    if damping * dt >= 1.0:
        raise DeckError(f"{key} = {damping!r} 1/s times the time step {fmt(dt)} s is {fmt(damping * dt)}: "
                        f"the drag would remove more than the whole velocity in one step; expected a "
                        f"damping below {fmt(1.0 / dt)} 1/s")


DENSEST_FRACTION = 0.7405   # no packing of spheres is denser (Kepler): the smallest possible cell


def granular_checks(n, density, r_min, r_max, mean_volume, size_keys):
    """Masses and memory of a granular sample of ``n`` spheres (radii in [r_min, r_max] [m], mean
    volume [m^3]); returns the edge [m] of its cell at the densest packing."""
    check_sphere(density, r_min, r_max, f"{size_keys}, sample.density")
    check_memory(n, 0.0, PAIRS_PER_ELEMENT * n, size_keys, f"{fmt(n)} spheres and {fmt(PAIRS_PER_ELEMENT * n)} "
                                                            f"contact pairs")
    return (n * mean_volume / DENSEST_FRACTION) ** (1.0 / 3.0)
