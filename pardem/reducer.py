"""Global measurements: plate forces and the least-squares strain. PHYSICS.md section 5.

Each rank sums over its owned elements; one ``Communicator.sum`` completes the sums, so results do
not depend on the number of ranks beyond floating-point summation order.

Strain: the displacement field ``U = x - x0`` of the kept elements (``FLAG_NEAR_PLATE`` unset) is
fitted by ``U = H X0 + c`` in the least-squares sense; ``eps = (H + H^T) / 2``. Compression is
negative strain; plate forces are positive in compression.
"""
import numpy as np
from numba import njit

from pardem.state import FLAG_NEAR_PLATE


@njit(cache=True, error_model="numpy")
def strain_sums(x, x0, flags, n_owned, origin, out):
    """Fill ``out`` [25] with n, sum X, sum U, sum X X^T (9), sum X U^T (9) over kept owned rows.

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


class Reducer:
    """Samples the global plate forces and strain of a ``Simulation`` with one collective."""

    def __init__(self, comm, origin):
        self.comm = comm
        self.origin = np.asarray(origin, dtype=np.float64)
        self._local = np.empty(25 + 2)

    def sample(self, sim):
        """Dict with time, step, plate displacement, plate forces (fixed, moving), H and eps."""
        e = sim.elements
        strain_sums(e.x, e.x0, e.flags, e.n_owned, self.origin, self._local[:25])
        self._local[25:27] = sim.plates.force_local
        g = self.comm.sum(self._local)
        H = gradient_from_sums(g[:25])
        return {
            "time": sim.time,
            "step": sim.step_count,
            "plate_displacement": sim.plates.displacement(),
            "force_fixed": float(g[25]),
            "force_moving": float(g[26]),
            "H": H,
            "eps": strain_tensor(H),
        }
