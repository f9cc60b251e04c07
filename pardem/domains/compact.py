"""Compact domains: dense random packings of polydisperse spheres, bonded where they touch.
docs/physics.md section 4.

Protocol: soft-sphere jamming (O'Hern et al. 2003), standard, fast and well understood; it gives a
homogeneous, statistically isotropic packing.

1. ``n`` radii ``R (1 + d U)``, ``U`` uniform in [-1, 1], then ``n`` uniform random centres in the
   box, all drawn from ``numpy.random.default_rng(seed)`` in that order. ``n`` follows from the box
   volume ``V``, the requested mean radius ``R`` and the target fraction ``phi_t = 0.64``:
   ``n = round(phi_t V / (4/3 pi R^3 (1 + d^2)))`` (``E[(1 + d U)^3] = 1 + d^2``).
2. Harmonic overlap energy ``U = 1/2 sum delta^2`` over overlapping pairs and sphere-wall contacts
   (unit stiffness, lengths in units of ``R``: the ``linear_contact`` normal law with ``kn = 1`` on
   the ``contact_frame`` pair geometry), minimised by FIRE (Bitzek et al. 2006, with the
   semi-implicit Euler step and the half-step back-off of FIRE 2.0, Guenole et al. 2020; the
   power, mixing and back-off kernels of ``pardem.physics.fire``) over the Verlet list of
   ``pardem.physics.neighbours``. All radii are scaled by one common factor, so
   the shape of the size distribution is kept.
3. The random centres are quenched at a solid fraction of 0.66 (above jamming), then the radius
   scale is bisected: a state is jammed when its energy has not vanished (``U / n > 1e-14``)
   after ``MAX_ITERATIONS`` FIRE steps; the fraction steps down from a jammed state, up from an
   unjammed one, and the step (0.01 at first) is halved at each change, down to ``1e-4`` relative.
   The last jammed state is kept: its overlaps are of the order of that step (max overlap / R ~
   1e-4), and its contact network, rattlers aside, is within a few contacts of isostatic (mean
   contact number 6), as at the jamming point. Quenching from above, rather than inflating from below, matters with capped
   minimisations: unjammed states just below jamming relax slowly and would be taken for jammed,
   while just above it they unjam in a few hundred steps. The cap trades ~1e-4 on the jamming
   fraction for time (a fully converged minimisation near jamming needs ~1e5 steps).
4. Boundaries: the faces normal to ``flat_axis`` (the loading axis) are flat walls, the other
   axes are periodic. A packing cut out of a periodic cell has faces rough on the scale of a
   radius, far more than the plate travel of a compression test (0.1 R at 0.5 % strain): the
   plate then bears on a handful of protruding elements, and the measured force and modulus are
   those of local contacts (seen on a 4 mm cube: fixed-plate force 5x below the moving one,
   slope and secant moduli 54 and 21 MPa). Walls give faces on which ~70 % of a layer touches the
   plate from the start (a 12 mm column: slope and secant moduli within 0.1 %). The other axes stay periodic because walls lower the density next to them: each wall
   pair costs ~0.29 / (L / R) of solid fraction (10 mm cube, R = 0.238 mm: 0.642 fully periodic,
   0.635 with one wall pair; walls on all six faces would give ~0.62). So boxes shorter than
   about 40 radii along ``flat_axis`` may not reach 0.63 and are refused (``MIN_FRACTION``); the
   other edges matter little (periodic; 12 radii still give 0.632-0.635 with 48 along it).

The solid fraction reported is ``sum V_e / V_box`` (the overlap lenses, ~1e-9 of the volume, are
not subtracted). The final mean radius differs from the requested one by the cube root of the
ratio of the jamming and target fractions (under 1 %).

Bonds (``bonded_pairs``, ``compact_domain``) join the elements whose surface gap
``|x_j - x_i| - R_i - R_j`` is below ``gap``, found by ``build_pairs`` without periodicity: the
packing is used as the box it was built in, so no bond crosses the periodic boundary, and
spheres stick out of the periodic faces by up to a radius (the box is the section they
represent).

Everything here is a pure function of its arguments (no MPI, no files, no global state): the same
seed gives bitwise the same packing on any process, so a caller may build on one rank and
broadcast, or build different realisations on different ranks. The FIRE loop and the force kernel
are Numba; the Python layer only rebuilds the Verlet list (every ``skin / 2`` of travel) and runs
the bisection (~15 minimisations). The 10 mm cube (11,200 elements) takes about 15 s on one core.

References
----------
Bitzek, Koskinen, Gaehler, Moseler, Gumbsch, Phys. Rev. Lett. 97, 170201 (2006) (FIRE).
Guenole et al., Comput. Mater. Sci. 175, 109584 (2020) (FIRE 2.0).
O'Hern, Silbert, Liu, Nagel, Phys. Rev. E 68, 011306 (2003) (jamming protocol, phi_J ~ 0.64).
"""
from dataclasses import dataclass

import numpy as np
from numba import njit

from pardem.physics import fire
from pardem.physics.contact_frame import overlap, pair_separation
from pardem.physics.linear_contact import linear_energy, linear_normal
from pardem.physics.neighbours import VerletList, build_pairs

TARGET_FRACTION = 0.64      # sets the element count; the packing ends at its own jamming fraction
MIN_FRACTION = 0.63         # guaranteed solid fraction (docs/physics.md section 4)
QUENCH_FRACTION = 0.66      # first minimisation, from the random centres: above jamming
START_STEP = 0.01           # first change of the solid fraction
FRACTION_TOLERANCE = 1e-4   # relative step at which the bisection stops
MAX_FRACTION = 0.74         # no random packing jams above (a close-packed crystal: 0.7405)
JAMMED_ENERGY = 1e-14       # U / n below which a state is unjammed (units of R^2)
FORCE_TOLERANCE = 1e-11     # a minimum: every |F_i| below (units of R; jammed forces ~1e-5)
MAX_ITERATIONS = 3000       # FIRE steps per minimisation; still overlapping after them: jammed
SKIN = 0.3                  # Verlet skin (units of R)
MIN_EDGE = 6.0              # box edges shorter than this many mean radii cannot hold a packing
RELIABLE_EDGE = 40.0        # flat_axis edges of this many mean radii jam above MIN_FRACTION

# FIRE parameters (Bitzek et al. 2006); time in units of sqrt(m / k), unit masses and stiffness
N_DELAY = 5
F_INC = 1.1
F_DEC = 0.5
ALPHA_START = 0.1
F_ALPHA = 0.99
DT_START = 0.05
DT_MAX = 0.5        # about 2 / omega_max (omega_max^2 ~ 2 Z k / m, Z ~ 6); FIRE's back-off catches overshoots
DT_MIN = 1e-4

# status codes of the FIRE kernel
_UNJAMMED, _CONVERGED, _REBUILD, _MAX_ITER = 0, 1, 2, 3


@dataclass(frozen=True)
class CompactPacking:
    """A jammed packing in ``box``: centres ``positions`` [n, 3] (m), ``radii`` [n] (m).

    Centres lie in ``[0, box)`` along the periodic axes and between the walls along ``flat_axis``
    (None: periodic along all three). ``solid_fraction`` = sum of the sphere volumes / box volume;
    ``mean_radius`` [m] is the final mean radius (``radius`` is the requested one);
    ``max_overlap`` and ``max_wall_overlap`` are the largest overlaps between two spheres (periodic
    images included) and with a wall, over the mean radius; ``minimisations`` and ``iterations``
    count the FIRE runs and steps.
    """
    positions: np.ndarray
    radii: np.ndarray
    box: tuple
    radius: float
    dispersity: float
    seed: int
    flat_axis: object       # 0, 1, 2 or None
    solid_fraction: float
    mean_radius: float
    max_overlap: float
    max_wall_overlap: float
    minimisations: int
    iterations: int

    @property
    def n(self) -> int:
        return len(self.radii)

    def matches(self, box, radius, dispersity, seed, flat_axis) -> bool:
        """True when this packing is the one ``compact_packing`` builds from these arguments."""
        return (tuple(float(b) for b in box) == self.box and float(radius) == self.radius
                and float(dispersity) == self.dispersity and int(seed) == self.seed
                and flat_axis == self.flat_axis)


# -- kernels --------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def overlap_forces(x, radius, pi, pj, shift, length, walls, f):
    """Harmonic overlap energy and forces ``f = -dU/dx`` [n, 3] of spheres and flat walls.

    ``U = 1/2 sum delta^2`` (unit stiffness) over the pairs ``(pi[k], pj[k])``, branch vector
    ``(x[j] - x[i]) + shift[k]``, and over the walls at ``0`` and ``length[d]`` along each axis
    ``d`` with ``walls[d]`` (overlap ``R_i - x_id`` and ``x_id + R_i - length[d]``).
    Returns ``(energy, largest pair overlap, largest wall overlap)``.
    """
    for k in range(x.shape[0]):
        f[k, 0] = 0.0
        f[k, 1] = 0.0
        f[k, 2] = 0.0
    energy = 0.0
    worst = 0.0
    for k in range(pi.shape[0]):
        i = pi[k]
        j = pj[k]
        d0, d1, d2, dist2, _, _, s = pair_separation(i, j, shift[k, 0], shift[k, 1], shift[k, 2],
                                                     x, radius)
        if dist2 < s * s and dist2 > 0.0:     # coincident centres have no direction
            dist, delta = overlap(dist2, s)
            energy += linear_energy(1.0, delta)
            if delta > worst:
                worst = delta
            c = linear_normal(1.0, 1.0, delta, 0.0, 0.0, False) / dist
            f[i, 0] -= c * d0
            f[i, 1] -= c * d1
            f[i, 2] -= c * d2
            f[j, 0] += c * d0
            f[j, 1] += c * d1
            f[j, 2] += c * d2
    worst_wall = 0.0
    for d in range(3):
        if not walls[d]:
            continue
        for k in range(x.shape[0]):
            low = radius[k] - x[k, d]
            high = x[k, d] + radius[k] - length[d]
            if low > 0.0:
                energy += linear_energy(1.0, low)
                f[k, d] += linear_normal(1.0, 1.0, low, 0.0, 0.0, False)
                worst_wall = max(worst_wall, low)
            if high > 0.0:
                energy += linear_energy(1.0, high)
                f[k, d] -= linear_normal(1.0, 1.0, high, 0.0, 0.0, False)
                worst_wall = max(worst_wall, high)
    return energy, worst, worst_wall


@njit(cache=True, error_model="numpy")
def fire_relax(x, v, f, radius, pi, pj, shift, length, walls, state, budget, max_iter, jammed_energy,
               force_tol):
    """FIRE minimisation of ``overlap_forces`` from ``x``, ``v`` (unit masses), in place.

    ``state`` = [dt, alpha, n_positive, iterations, energy] carries the FIRE state across calls.
    Returns a status: 0 energy per element below ``jammed_energy`` (unjammed), 1 every force below
    ``force_tol`` (a minimum), 2 some element may have moved ``budget`` since the call (rebuild the
    Verlet list and call again), 3 ``max_iter`` steps done.
    """
    n = x.shape[0]
    dt, alpha, n_pos = state[0], state[1], state[2]
    moved = 0.0     # bound on any element's travel since the call
    energy = overlap_forces(x, radius, pi, pj, shift, length, walls, f)[0]
    status = _MAX_ITER
    for _ in range(max_iter):
        if moved > budget:     # first: beyond it, the list may miss pairs and the energy be wrong
            status = _REBUILD
            break
        state[4] = energy
        if energy < jammed_energy * n:
            status = _UNJAMMED
            break
        fmax2 = 0.0
        for k in range(n):
            fk2 = f[k, 0] ** 2 + f[k, 1] ** 2 + f[k, 2] ** 2
            if fk2 > fmax2:
                fmax2 = fk2
        if fmax2 < force_tol * force_tol:
            status = _CONVERGED
            break
        state[3] += 1.0
        if fire.power_sums(v, f, n)[0] > 0.0:
            n_pos += 1.0
            if n_pos > N_DELAY:
                dt = min(dt * F_INC, DT_MAX)
                alpha *= F_ALPHA
        else:
            # uphill: step half back, stop, and restart cautiously (FIRE 2.0 back-off)
            n_pos = 0.0
            dt = max(dt * F_DEC, DT_MIN)
            alpha = ALPHA_START
            moved += 0.5 * dt * np.sqrt(fire.back_off(x, v, 0.5 * dt, n))
        for k in range(n):     # semi-implicit Euler: kick, then FIRE's mixing, then drift
            for d in range(3):
                v[k, d] += dt * f[k, d]
        _, vv, ff = fire.power_sums(v, f, n)
        fire.mix(v, f, alpha, np.sqrt(vv / ff) if ff > 0.0 else 0.0, n)
        vmax2 = 0.0
        for k in range(n):
            vk2 = 0.0
            for d in range(3):
                x[k, d] += dt * v[k, d]
                vk2 += v[k, d] * v[k, d]
            if vk2 > vmax2:
                vmax2 = vk2
        moved += dt * np.sqrt(vmax2)
        energy = overlap_forces(x, radius, pi, pj, shift, length, walls, f)[0]
    state[0], state[1], state[2] = dt, alpha, n_pos
    return status


@njit(cache=True, error_model="numpy")
def _find(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit(cache=True, error_model="numpy")
def connected_components(n, pi, pj):
    """Component label [n] of each node of the graph with edges ``(pi[k], pj[k])`` (union-find);
    labels are the smallest node of each component."""
    parent = np.arange(n)
    for k in range(pi.shape[0]):
        a = _find(parent, pi[k])
        b = _find(parent, pj[k])
        if a < b:
            parent[b] = a
        elif b < a:
            parent[a] = b
    label = np.empty(n, dtype=np.int64)
    for k in range(n):
        label[k] = _find(parent, k)
    return label


# -- Python layer ---------------------------------------------------------------------------------

class _Minimiser:
    """FIRE runs of one packing (lengths in units of R) with its Verlet list."""

    def __init__(self, x, shape, box, walls):
        self.x = x
        self.shape = shape                  # radii at scale 1
        self.box = box
        self.walls = np.asarray(walls, dtype=np.bool_)
        self.periodic = ~self.walls
        self.gid = np.arange(len(x), dtype=np.int64)
        self.vlist = VerletList(SKIN, periodic=tuple(self.periodic), box_lo=np.zeros(3), box_hi=box)
        self.f = np.zeros_like(x)
        self.iterations = 0
        self.runs = 0

    def _rebuild(self, radius):
        # wrapping (periodic axes only) is allowed at a rebuild, and keeps the int8 shifts small
        p = self.periodic
        self.x[:, p] -= np.floor(self.x[:, p] / self.box[p]) * self.box[p]
        self.vlist.rebuild(self.x, radius, self.gid, len(self.x))
        i, j, shift = self.vlist.kernel_arrays()
        return i, j, np.zeros((len(i), 3)) if shift is None else shift

    def relax(self, scale, max_iter):
        """Minimise at radius ``scale``; returns (jammed, energy per element)."""
        radius = self.shape * scale
        v = np.zeros_like(self.x)
        state = np.array([DT_START, ALPHA_START, 0.0, 0.0, 0.0])
        self.runs += 1
        while True:
            i, j, shift = self._rebuild(radius)
            status = fire_relax(self.x, v, self.f, radius, i, j, shift, self.box, self.walls, state,
                                0.5 * SKIN, max_iter - int(state[3]), JAMMED_ENERGY, FORCE_TOLERANCE)
            if status != _REBUILD:
                break
        self.iterations += int(state[3])
        return status != _UNJAMMED, state[4] / len(self.x)

    def overlaps(self, scale):
        """Largest overlap between two spheres and between a sphere and a wall (units of R)."""
        radius = self.shape * scale
        i, j, shift = self._rebuild(radius)
        return overlap_forces(self.x, radius, i, j, shift, self.box, self.walls, np.zeros_like(self.x))[1:]


def element_count(box, radius, dispersity, fraction=TARGET_FRACTION):
    """Number of spheres of mean radius ``radius`` [m] filling ``fraction`` of ``box`` [m]."""
    mean_volume = 4.0 / 3.0 * np.pi * radius**3 * (1.0 + dispersity**2)
    return int(round(fraction * float(np.prod(box)) / mean_volume))


def compact_packing(box, radius, dispersity=0.1, seed=0, flat_axis=None):
    """The jammed packing of seed ``seed`` in ``box`` [3] (m); see the module docstring.

    ``radius`` [m] is the requested mean radius, ``dispersity`` in [0, 0.5) the half-width of the
    uniform radius distribution relative to it. ``flat_axis`` (0, 1, 2 or None): the axis normal to
    the two flat walls of the box; the other axes are periodic (all three with None). Raises
    ValueError for a box too small for a packing (an edge below 6 radii) or a jamming fraction
    below 0.63.
    """
    box = np.asarray(box, dtype=np.float64).reshape(3)
    R = float(radius)
    d = float(dispersity)
    if not 0.0 <= d < 0.5:
        raise ValueError(f"dispersity = {d}: expected a number in [0, 0.5)")
    if flat_axis not in (None, 0, 1, 2):
        raise ValueError(f"flat_axis = {flat_axis!r}: expected 0, 1, 2 or None")
    if not R > 0.0 or not np.all(box > 0.0):
        raise ValueError("radius and box edges must be positive")
    if np.any(box < MIN_EDGE * R):
        raise ValueError(f"every box edge must be at least {MIN_EDGE:g} mean radii ({MIN_EDGE * R:.6g} m)")
    n = element_count(box, R, d)
    rng = np.random.default_rng(int(seed))
    shape = 1.0 + d * rng.uniform(-1.0, 1.0, n)
    L = box / R
    x = rng.uniform(0.0, 1.0, (n, 3)) * L
    volume_at_unit_scale = 4.0 / 3.0 * np.pi * float(np.sum(shape**3)) / float(np.prod(L))

    def scale_of(phi):
        return (phi / volume_at_unit_scale) ** (1.0 / 3.0)

    walls = np.zeros(3, dtype=np.bool_)
    if flat_axis is not None:
        walls[flat_axis] = True
    m = _Minimiser(x, shape, L, walls)
    phi = QUENCH_FRACTION
    step = START_STEP
    jammed_state = None     # (centres, fraction) of the last jammed state
    previous = None
    while True:
        jammed, _ = m.relax(scale_of(phi), MAX_ITERATIONS)
        if jammed:
            if phi < MIN_FRACTION:
                raise ValueError(f"the packing is still jammed at a solid fraction of {phi:.4f}, "
                                 f"below {MIN_FRACTION}")
            jammed_state = (m.x.copy(), phi)
        if previous is not None and jammed != previous:
            step *= 0.5
        previous = jammed
        if jammed_state is not None and step < FRACTION_TOLERANCE * phi:
            break
        phi = phi - step if jammed else phi + step
        if phi > MAX_FRACTION:
            raise ValueError(f"the packing did not jam below a solid fraction of {MAX_FRACTION}")
    m.x, phi = jammed_state
    scale = scale_of(phi)
    worst, worst_wall = m.overlaps(scale)
    radii = shape * scale * R
    fraction = 4.0 / 3.0 * np.pi * float(np.sum(radii**3)) / float(np.prod(box))
    if fraction < MIN_FRACTION:
        raise ValueError(f"the packing jammed at a solid fraction of {fraction:.4f}, below {MIN_FRACTION}")
    mean = float(np.mean(shape * scale))
    return CompactPacking(positions=m.x * R, radii=radii, box=tuple(float(b) for b in box), radius=R,
                          dispersity=d, seed=int(seed), flat_axis=flat_axis, solid_fraction=fraction,
                          mean_radius=float(np.mean(radii)), max_overlap=float(worst / mean),
                          max_wall_overlap=float(worst_wall / mean), minimisations=m.runs,
                          iterations=m.iterations)


def bonded_pairs(positions, radii, gap):
    """Pairs [m, 2] (int64, i < j, sorted) whose surface gap ``|x_j - x_i| - R_i - R_j`` is below
    ``gap`` [m] (overlapping pairs included); no periodicity."""
    n = len(radii)
    pairs, _ = build_pairs(positions, radii, np.arange(n, dtype=np.int64), n, n, float(gap))
    pairs = np.sort(pairs.astype(np.int64), axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def compact_domain(packing, gap):
    """Centres [n, 3] (m), radii [n] (m) and bonded pairs [m, 2] of the bonded box of ``packing``.

    Pairs whose surface gap is below ``gap`` [m] are bonded (``bonded_pairs``). Elements outside
    the largest bonded cluster (rattlers with no neighbour within the gap, and the rare small
    groups cut off at the periodic faces) are removed: nothing would hold them between the plates,
    and their zero displacement would bias the least-squares strain. Elements are ordered by cells
    of one mean diameter (x slowest, then y, then z), so neighbours are close in memory and ids
    follow space; pairs are (i < j), sorted. Raises ValueError when the removals leave a solid
    fraction below ``MIN_FRACTION``.
    """
    x, r = packing.positions, packing.radii
    pairs = bonded_pairs(x, r, gap)
    label = connected_components(len(r), pairs[:, 0], pairs[:, 1])
    keep = label == np.argmax(np.bincount(label))
    fraction = 4.0 / 3.0 * np.pi * float(np.sum(r[keep] ** 3)) / float(np.prod(packing.box))
    if fraction < MIN_FRACTION:
        raise ValueError(f"removing the {int(np.sum(~keep))} elements not bonded to the main cluster "
                         f"leaves a solid fraction of {fraction:.4f}, below {MIN_FRACTION}")
    h = 2.0 * packing.mean_radius
    cell = np.floor(x / h).astype(np.int64)
    order = np.lexsort((x[:, 2], cell[:, 1], cell[:, 0]))
    order = order[keep[order]]
    new = np.full(len(r), -1, dtype=np.int64)
    new[order] = np.arange(len(order))
    pairs = new[pairs[keep[pairs[:, 0]] & keep[pairs[:, 1]]]]
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    return x[order], r[order], pairs
