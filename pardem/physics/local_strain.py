"""Local strain of a granular assembly: the least-squares displacement gradient of each grain's
neighbourhood (localisation).

For grain i with neighbours j (pairs within a distance, or contacts) and reference branch vectors
``b_ij = x_j - x_i`` (periodic images resolved by the caller) and relative displacements
``du_ij = u_j - u_i``, the gradient ``G_i`` minimises ``sum_j |du_ij - G_i b_ij|^2``:
``G_i = (sum_j du_ij b_ij^T) (sum_j b_ij b_ij^T)^-1``. Its symmetric part is the strain, its
skew part the local rotation. A pair adds the same two outer products to both ends (the signs of
b and du flip together), so one pass over the pairs fills every grain's sums. A grain whose
neighbours do not span the space (fewer than ``dim`` independent branches) gets NaN. An affine
displacement field ``u = G x + c`` is recovered exactly (to round-off) at every grain: the test.
"""
import numpy as np
from numba import njit


@njit(cache=True)
def _sums(i, j, branch, du, n, dim, A, B):
    for k in range(i.shape[0]):
        a, b = i[k], j[k]
        for r in range(dim):
            for c in range(dim):
                bb = branch[k, r] * branch[k, c]
                ub = du[k, r] * branch[k, c]
                A[a, r, c] += bb
                A[b, r, c] += bb
                B[a, r, c] += ub
                B[b, r, c] += ub


def displacement_gradient(n, i, j, branch, du, dim=2, rcond=1e-10):
    """Per-grain least-squares displacement gradient ``G`` [n, dim, dim] (``G[a, r, c] = du_r /
    dx_c``) from the pairs ``i``, ``j`` [n_p] with branch vectors ``branch`` [n_p, >= dim] [m]
    (``x_j - x_i`` in the reference state) and relative displacements ``du`` [n_p, >= dim] [m]
    (``u_j - u_i``). Grains whose branch tensor is singular (its smallest eigenvalue below
    ``rcond`` times its largest) get NaN."""
    i = np.ascontiguousarray(i, dtype=np.int64)
    j = np.ascontiguousarray(j, dtype=np.int64)
    branch = np.ascontiguousarray(np.asarray(branch, dtype=np.float64)[:, :dim])
    du = np.ascontiguousarray(np.asarray(du, dtype=np.float64)[:, :dim])
    A = np.zeros((n, dim, dim))
    B = np.zeros((n, dim, dim))
    _sums(i, j, branch, du, n, dim, A, B)
    G = np.full((n, dim, dim), np.nan)
    w = np.linalg.eigvalsh(A)                       # ascending, per grain
    ok = w[:, 0] > rcond * np.maximum(w[:, -1], 0.0)
    ok &= w[:, -1] > 0.0
    # G A = B  ->  G = B A^-1; A is symmetric, so solve A G^T = B^T
    G[ok] = np.transpose(np.linalg.solve(A[ok], np.transpose(B[ok], (0, 2, 1))), (0, 2, 1))
    return G


def strain_measures(G):
    """From gradients ``G`` [n, dim, dim]: dict of ``strain`` (symmetric part) [n, dim, dim],
    ``rotation`` [n] (2D: the rotation angle (G_yx - G_xy) / 2 [rad]; 3D: [n, 3] the axial
    vector), ``volumetric`` [n] (trace), ``shear`` [n] (the largest shear: in 2D
    ``sqrt(((e_xx - e_yy) / 2)^2 + e_xy^2)``, in 3D half the difference of the extreme principal
    strains) — small-strain measures of an increment."""
    G = np.asarray(G, dtype=np.float64)
    dim = G.shape[1]
    eps = 0.5 * (G + np.transpose(G, (0, 2, 1)))
    skew = 0.5 * (G - np.transpose(G, (0, 2, 1)))
    if dim == 2:
        rotation = skew[:, 1, 0]
        shear = np.sqrt((0.5 * (eps[:, 0, 0] - eps[:, 1, 1])) ** 2 + eps[:, 0, 1] ** 2)
    else:
        rotation = np.column_stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]])
        good = np.all(np.isfinite(eps), axis=(1, 2))
        shear = np.full(len(G), np.nan)
        if good.any():
            w = np.linalg.eigvalsh(eps[good])
            shear[good] = 0.5 * (w[:, -1] - w[:, 0])
    return {"strain": eps, "rotation": rotation, "volumetric": np.trace(eps, axis1=1, axis2=2),
            "shear": shear}
