"""Static linear response of a network of beam bonds between two rigid frictionless plates: one
sparse solve, no time stepping, damping or plate dynamics (docs/physics.md sections 2 and 5). The
compression test's modulus computed independently of its time loop.

Bond (section 2, to first order): with ``n`` the unit chord i -> j, ``du = u_j - u_i``,
``P = I - n n`` and the end rotations relative to the chord ``t_k = P theta_k - n x du / L0``, its
energy is::

    1/2 ka (n.du)^2 + 1/2 kt (n.(theta_j - theta_i))^2 + (2 kb / L0)(t_i.t_i + t_i.t_j + t_j.t_j)

(``ka = E S / L0`` [N/m], ``kt = G I0 / L0`` [N m/rad], ``kb = E I`` [N m^2], as ``Bonds`` stores
them): in the chord frame, the textbook 12 x 12 Euler-Bernoulli frame element. The section is
round, one ``kb`` for both bending planes, so no body axes enter.

Plates (section 5): normal to ``axis``, the fixed one at ``plate_low``, the moving one at
``plate_high`` displaced by 1 m towards it; every response is per metre of that displacement. An
element whose gap to a plate (``|x_a - plate| - R``) is below ``touch`` [m] is tied to it by the
linear spring ``plate_stiffness`` along the load only (frictionless), its gap closed. The plates
leave the translations across the load free: springs ``hold * plate_stiffness`` on every element's
two lateral translations take them (and that fraction of the lateral load).

Assumes: small displacements about the given positions; bonds elastic, intact and at rest (no
pre-stress; pass the intact ones only); element contacts carry nothing (every touching pair of the
built domains is bonded); every element is bonded to a cluster tied to both plates and not lying on
one line along the load (whose spin about it nothing holds: the matrix is singular otherwise); a tie
pushes or pulls alike, so a tied element that the plate pulls (``PlateResponse.pulled``) would leave
a real plate, and the result is then not the contact problem's.
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl


def stiffness_matrix(x, i, j, L0, ka, kb, kt):
    """Stiffness matrix ``K`` [6 n, 6 n] (scipy CSR) of the beam bonds joining rows ``i``, ``j``
    [n_b] of the elements at ``x`` [n, 3] [m]; ``L0`` [m], ``ka``, ``kb``, ``kt`` [n_b] each (module
    docstring). DOFs per element ``(u [m], theta [rad])``; the generalised force (forces [N],
    moments [N m]) of a displacement ``z`` is ``-K z``."""
    x = np.asarray(x, dtype=np.float64)
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)
    L0 = np.asarray(L0, dtype=np.float64)
    d = x[j] - x[i]
    nv = d / np.linalg.norm(d, axis=1)[:, None]
    S = np.cross(nv[:, None, :], np.eye(3)).transpose(0, 2, 1) / L0[:, None, None]   # S v = n x v / L0
    P = np.eye(3)[None] - nv[:, :, None] * nv[:, None, :]
    # rows: n.du, n.(theta_j - theta_i), t_i (3), t_j (3); columns: u_i, theta_i, u_j, theta_j
    B = np.zeros((len(L0), 8, 12))
    B[:, 0, 0:3], B[:, 0, 6:9] = -nv, nv
    B[:, 1, 3:6], B[:, 1, 9:12] = -nv, nv
    for row, col in ((2, 3), (5, 9)):
        B[:, row:row + 3, col:col + 3] = P
        B[:, row:row + 3, 0:3] = S
        B[:, row:row + 3, 6:9] = -S
    c = 2.0 * np.asarray(kb, dtype=np.float64) / L0
    D = np.zeros((len(L0), 8, 8))
    D[:, 0, 0], D[:, 1, 1] = ka, kt
    for q in range(2, 5):
        D[:, q, q] = D[:, q + 3, q + 3] = 2.0 * c
        D[:, q, q + 3] = D[:, q + 3, q] = c
    Kb = np.einsum("bki,bkl,blj->bij", B, D, B)
    dof = np.concatenate([6 * i[:, None] + np.arange(6), 6 * j[:, None] + np.arange(6)], axis=1)
    m = 6 * len(x)
    return sp.coo_matrix((Kb.ravel(), (np.repeat(dof, 12, axis=1).ravel(), np.tile(dof, (1, 12)).ravel())),
                         shape=(m, m)).tocsr()


@dataclass(frozen=True)
class PlateResponse:
    """The network's response per metre of the moving plate's displacement towards the fixed one.

    u [n, 3] translations [m/m]; theta [n, 3] rotations [rad/m]; low, high [n] bool: the elements
    tied to the fixed (low) and the moving (high) plate; gap [n]: each element's initial gap to the
    nearer plate [m]; force_low, force_high: the force on each plate [N/m], compression positive
    (equal but for the ``hold`` springs' share); axis."""
    u: np.ndarray
    theta: np.ndarray
    low: np.ndarray
    high: np.ndarray
    gap: np.ndarray
    force_low: float
    force_high: float
    axis: int

    @property
    def pulled(self):
        """[n] bool: the tied elements the plate pulls (the tie's force on them is tensile)."""
        ua = self.u[:, self.axis]
        return (self.low & (ua > 0.0)) | (self.high & (ua < -1.0))


def plate_response(x, radius, i, j, L0, ka, kb, kt, axis, plate_low, plate_high, plate_stiffness,
                   touch, hold=1e-9):
    """``PlateResponse`` of the bonds (``stiffness_matrix``'s arguments) of the elements at ``x``
    [n, 3] [m] of radii ``radius`` [n] [m] between plates normal to ``axis`` (0, 1, 2) at
    ``plate_low`` < ``plate_high`` [m], of linear normal stiffness ``plate_stiffness`` [N/m],
    tying the elements within ``touch`` [m] of a plate; ``hold``: the lateral springs over the
    plate stiffness (module docstring)."""
    x, radius = np.asarray(x, dtype=np.float64), np.asarray(radius, dtype=np.float64)
    n, a, kn = len(x), int(axis), float(plate_stiffness)
    gap_low, gap_high = x[:, a] - radius - plate_low, plate_high - x[:, a] - radius
    low, high = gap_low < touch, gap_high < touch
    diag = np.zeros(6 * n)
    diag[6 * np.nonzero(low | high)[0] + a] += kn
    for other in {0, 1, 2} - {a}:
        diag[6 * np.arange(n) + other] += hold * kn
    f = np.zeros(6 * n)
    f[6 * np.nonzero(high)[0] + a] = -kn          # the moving plate's spring, its end moved by -1 m
    K = stiffness_matrix(x, i, j, L0, ka, kb, kt) + sp.diags(diag)
    z = spl.spsolve(K.tocsc(), f).reshape(n, 6)
    u = z[:, :3]
    return PlateResponse(u=u, theta=z[:, 3:], low=low, high=high, gap=np.minimum(gap_low, gap_high),
                         force_low=kn * float(np.sum(-u[low, a])),
                         force_high=kn * float(np.sum(u[high, a] + 1.0)), axis=a)
