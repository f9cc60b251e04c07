"""Global measurements: plate forces and the least-squares strain. docs/physics.md section 5.

Each rank sums over its owned elements; one ``Communicator.sum`` completes the sums, so results do
not depend on the number of ranks beyond floating-point summation order; the granular measures of
``reproducible`` contacts are exact sums instead (``parallel.exact_sum``): the same bits on any
number of ranks.

Strain: the displacement field ``U = x - x0`` of the kept elements (``FLAG_NEAR_PLATE`` unset) is
fitted by ``U = H X0 + c`` in the least-squares sense; ``eps = (H + H^T) / 2``. Compression is
negative strain; plate forces are positive in compression.
"""
import numpy as np
from numba import njit

from pardem.engine.state import FLAG_NEAR_PLATE
from pardem.parallel import exact_sum
from pardem.physics.structure import lens_area


@njit(cache=True, error_model="numpy")
def strain_sums(x, x0, flags, n_owned, origin, out):
    """Fill ``out`` [STRAIN_SUMS = 25] with n, sum X, sum U, sum X X^T (9), sum X U^T (9) over kept owned rows.

    X = x0 - origin (a fixed point near the domain centre, against round-off), U = x - x0.
    """
    for a in range(25):
        out[a] = 0.0
    X = np.empty(3)
    U = np.empty(3)
    for k in range(n_owned):
        if flags[k] & FLAG_NEAR_PLATE:
            continue
        for d in range(3):
            X[d] = x0[k, d] - origin[d]
            U[d] = x[k, d] - x0[k, d]
        out[0] += 1.0
        for d in range(3):
            out[1 + d] += X[d]
            out[4 + d] += U[d]
            for e in range(3):
                out[7 + 3 * d + e] += X[d] * X[e]
                out[16 + 3 * d + e] += X[d] * U[e]


def gradient_from_sums(s):
    """Displacement gradient H [3, 3] (H[a, b] = dU_a/dX_b) from the global sums of ``strain_sums``."""
    n = s[0]
    if n < 4:
        raise ValueError("fewer than 4 elements away from the plates: the strain fit is undefined")
    mx, mu = s[1:4] / n, s[4:7] / n
    A = s[7:16].reshape(3, 3) - n * np.outer(mx, mx)
    B = s[16:25].reshape(3, 3) - n * np.outer(mx, mu)
    # A H^T = B
    return np.linalg.solve(A, B).T


def strain_tensor(H):
    return 0.5 * (H + H.T)


def young_and_poisson(eps, force, axis, cross_section):
    """E = F / (S * -eps_aa) [Pa] and nu_ab = -eps_bb / eps_aa for the two other axes b."""
    names = "xyz"
    ea = eps[axis, axis]
    young = force / (cross_section * -ea) if ea != 0.0 else float("nan")
    nus = {}
    for b in range(3):
        if b != axis:
            nus[names[axis] + names[b]] = float(-eps[b, b] / ea) if ea != 0.0 else float("nan")
    return float(young), nus


STRAIN_SUMS = 25   # length of ``strain_sums``' output


class Reducer:
    """Samples the global plate forces, strain and bond damage of a ``Simulation`` with one
    collective."""
    # layout of the one reduced vector: strain sums, then the named entries below
    STRAIN = slice(0, STRAIN_SUMS)
    PLATE_FORCES = slice(STRAIN_SUMS, STRAIN_SUMS + 2)   # fixed, moving plate [N]
    BROKEN = STRAIN_SUMS + 2           # bonds broken so far
    BROKEN_STEP = STRAIN_SUMS + 3      # bonds broken in the step just taken
    YIELDED = STRAIN_SUMS + 4          # densifying bonds with plastic strain > 0
    WIDTH = STRAIN_SUMS + 5

    def __init__(self, comm, origin):
        self.comm = comm
        self.origin = np.asarray(origin, dtype=np.float64)
        self._local = np.empty(self.WIDTH)

    def sample(self, sim):
        """Dict with time, step, plate displacement, plate forces (fixed, moving), H and eps, and
        the bond counts: ``bonds_broken`` (all broken so far), ``bonds_broken_step`` (broken in the
        step just taken), ``bonds_yielded`` (densifying bonds with plastic strain > 0)."""
        e, b = sim.elements, sim.bonds
        loc = self._local
        strain_sums(e.x, e.x0, e.flags, e.n_owned, self.origin, loc[self.STRAIN])
        loc[self.PLATE_FORCES] = sim.plates.force_local
        once = b.counted_once(e.n_owned)
        loc[self.BROKEN] = np.count_nonzero(~b.intact[once])
        loc[self.BROKEN_STEP] = sim.bonds_broken_step
        loc[self.YIELDED] = np.count_nonzero(b.plastic[once] > 0.0) if b.densify_p0 > 0.0 else 0
        g = self.comm.sum(loc)
        H = gradient_from_sums(g[self.STRAIN])
        fixed, moving = g[self.PLATE_FORCES]
        return {
            "time": sim.time,
            "step": sim.step_count,
            "plate_displacement": sim.plates.displacement(),
            "force_fixed": float(fixed),
            "force_moving": float(moving),
            "H": H,
            "eps": strain_tensor(H),
            "bonds_broken": int(g[self.BROKEN]),
            "bonds_broken_step": int(g[self.BROKEN_STEP]),
            "bonds_yielded": int(g[self.YIELDED]),
        }


@njit(cache=True, error_model="numpy")
def overlap_volume(x, radius, pi, pj, shift, periodic, n_owned):
    """Volume [m^3] of the lenses shared by overlapping pairs whose ``i`` is owned (counted once).

    Lens of spheres R1, R2 at centre distance d < R1 + R2:
    ``pi (R1 + R2 - d)^2 (d^2 + 2 d (R1 + R2) - 3 (R1 - R2)^2) / (12 d)``.
    """
    v = 0.0
    terms = overlap_volumes(x, radius, pi, pj, shift, periodic, n_owned)
    for p in range(pi.shape[0]):
        v += terms[p]
    return v


@njit(cache=True, error_model="numpy")
def overlap_volumes(x, radius, pi, pj, shift, periodic, n_owned, dim=3):
    """The lens volume [m^3] of each pair [n_pairs] (``overlap_volume``'s terms; 0 for the pairs
    not overlapping or whose ``i`` is a ghost), for an exact sum; ``dim = 2``: the lens areas [m^2]
    of the disks (``pardem.physics.structure.lens_area``)."""
    out = np.zeros(pi.shape[0])
    for p in range(pi.shape[0]):
        i = pi[p]
        if i >= n_owned:
            continue
        j = pj[p]
        d2 = 0.0
        for a in range(3):
            da = x[j, a] - x[i, a]
            if periodic:
                da += shift[p, a]
            d2 += da * da
        r1 = radius[i]
        r2 = radius[j]
        s = r1 + r2
        if d2 >= s * s:
            continue
        d = np.sqrt(d2)
        if dim == 2:
            out[p] = lens_area(r1, r2, d)
            continue
        h = s - d
        out[p] = np.pi * h * h * (d2 + 2.0 * d * s - 3.0 * (r1 - r2) ** 2) / (12.0 * d)
    return out


def granular_measures(sim):
    """Global state of a granular ``Simulation`` in a periodic cell (collective). docs/physics.md section 11.

    Returns a dict: ``stress`` [3, 3] [Pa], the Love-Weber stress of the contacts of the last force
    evaluation, tension positive; ``pressure`` = -trace / 3 [Pa] (compression positive; 2D:
    -(s_xx + s_yy) / 2); ``Z`` = 2 N_c / N, the coordination number; ``solid_fraction``: sphere
    volumes minus the overlap lenses, over the cell volume (2D: disk areas minus the lens areas
    over L_x L_y); ``n_contacts``, ``kinetic_energy`` [J], ``contact_energy`` [J].
    """
    e, c = sim.elements, sim.contacts
    n = e.n_owned
    dim = getattr(sim.cell, "dimension", 3)
    vols = np.pi * e.radius[:n] ** 2 if dim == 2 else 4.0 / 3.0 * np.pi * e.radius[:n] ** 3
    spheres = float(np.sum(vols))
    shift = c.shift if c.shift is not None else np.zeros((0, 3))
    kin = sim.kinetic_energy()
    if c.reproducible:
        # the same bits on any number of ranks: exact sums of the per-element and per-pair terms
        sums, energy = c.global_sums(sim.comm)
        lens = overlap_volumes(e.x, e.radius, c.i, c.j, shift, c.shift is not None, n, dim)
        cols = np.zeros((max(n, len(lens)), 2))
        cols[:n, 0] = vols
        cols[:len(lens), 1] = lens
        vl = exact_sum.exact_sum(sim.comm, cols)
        counts = sim.comm.sum(np.array([c.n_touching, n], dtype=np.float64))   # integers: exact
        g = np.concatenate([sums, [counts[0], vl[0], vl[1], counts[1], energy]])
    else:
        lens = float(np.sum(overlap_volumes(e.x, e.radius, c.i, c.j, shift, c.shift is not None, n, dim))) \
            if dim == 2 else overlap_volume(e.x, e.radius, c.i, c.j, shift, c.shift is not None, n)
        g = sim.comm.sum(np.concatenate([c.sums, [spheres, lens, n, sim.contact_energy]]))
    stress = g[:9].reshape(3, 3) / sim.cell.volume
    # 2D: the in-plane pressure -(s_xx + s_yy) / 2 and disk areas over L_x L_y (PeriodicCell)
    pressure = sim.cell.pressure(stress) if dim == 2 else float(-np.trace(stress) / 3.0)
    space = sim.cell.area if dim == 2 else sim.cell.volume
    return {"stress": stress, "pressure": float(pressure),
            "Z": float(2.0 * g[9] / g[12]), "n_contacts": int(round(g[9])),
            "solid_fraction": float((g[10] - g[11]) / space),
            "kinetic_energy": kin, "contact_energy": float(g[13])}
