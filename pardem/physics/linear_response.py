"""Static linear response of a frictional contact network in a periodic cell: stiffness matrix,
non-affine relaxation under a small affine strain, elastic moduli. docs/physics.md sections 8, 11.

An independent second way to the moduli the isotropic protocol measures by dynamic relaxation
(``pardem.protocols.isotropic``): here the packing is not moved at all; its contact network is
linearised about the equilibrium state and the relaxed response is one sparse linear solve.
Pure numpy / scipy over arrays (no MPI, no files, none of the engine's kernels).

Network (``Network``): ``n`` grains, contacts ``(i, j)`` with branch vector ``d = x_j + s - x_i``
[m] (``s`` the periodic image shift, so the contact list already holds the periodic images), unit
normal ``n = d / r``, ``r = |d|``, the repulsive normal force ``fn`` [N], the normal tangent
stiffness ``kn = d fn / d delta`` [N/m], the tangential stiffness ``kt`` [N/m] and the arms
``l_i = R_i - delta / 2``, ``l_j`` [m] from the centres to the contact point (the engine's
``contact_frame`` conventions). The reference state must carry no tangential force (the
protocol's: the moduli start from a frictionless equilibrium with the history cleared); a
tangential force ``ft`` would add terms of relative order ``|ft| / fn * delta / r`` (1e-5 here).

Linearised contact law (the engine's Hertz-Mindlin kernel to first order, no sliding). Degrees
of freedom: per grain a translation ``u`` and a rotation ``theta`` [6]. Per contact, with
``P = I - n n``, ``dd = u_j - u_i + eps d`` (``eps`` the affine strain, symmetric [3, 3]) and
``c = l_i theta_i + l_j theta_j``::

    s_n = n . dd                  normal approach (delta changes by -s_n)
    w   = P dd + n x c            tangential displacement of the contact point of j relative to i
    g   = P dd                    rotation of the branch vector (times r)

    dF_i = kn s_n n + kt w - (fn / r) g,   dF_j = -dF_i
    dT_i = l_i n x (kt w),   dT_j = l_j n x (kt w)

``kn s_n n``: the Hertz force change; ``kt w``: the Mindlin spring loaded from zero (``dft = -kt
ds``, ``ds = -w``); ``-(fn / r) g``: the existing normal force turning with the normal (the
pre-stress or geometric term). These are minus the gradients of the contact energy
``E_c = kn s_n^2 / 2 + kt |w|^2 / 2 - fn |g|^2 / (2 r)``, so the stiffness matrix
``H = sum_c B_c^T D_c B_c`` is symmetric (``stiffness_matrix``). Rotations enter scaled by a
length ``scale`` (``phi = scale * theta``, default the mean radius) so that all entries are
stiffnesses [N/m]; the generalised force on ``phi`` is the torque over ``scale``.

Stress (Love-Weber, tension positive, ``sigma V = sum_c d (x) F_i``, as the engine) to first order::

    d sigma = (1/V) sum_c [ dd (x) F_i + d (x) dF_i ] - sigma tr(eps)         (V changes by tr eps)

Relaxation (``relax``): the non-affine displacement ``z`` solves ``H z = f_aff`` with
``f_aff = -sum_c B_c^T D_c y_c(eps)`` the out-of-balance forces of the affine map. ``H`` is
singular: (1) grains with fewer than 2 contacts (rattlers; at equilibrium their one contact
carries no force, so they follow their neighbour at no force and change no stress at first order)
are removed with their contacts, repeatedly; (2) only the largest connected cluster of the rest is
kept (a finite cluster of repulsive grains is free: it relaxes to zero force change); (3) the
three rigid translations of that cluster are removed by pinning the translation of one grain (the
stress depends on relative displacements only, so which grain does not matter: tested);
(4) what remains singular (e.g. the spin of a grain held by two diametrically opposite
contacts, which no affine load excites: ``f_aff`` is orthogonal to it) is handled by a Tikhonov
shift ``reg * mean(diag H)`` in the factorisation only, followed by iterative refinement with the
unshifted ``H``: the returned solution satisfies ``H z = f_aff`` to the reported relative
residual (about 1e-13), so the shift does not bias the result. The factorisation is scipy's
sparse LU (``splu``), reused for every strain mode.

Moduli (``moduli``) for the isotropic protocol's two increments (same conventions)::

    K  = d p / (-tr eps) with p = -tr(sigma) / 3,     eps = -I    (compression)
    mu = (d sigma_xx - d sigma_yy) / (2 (eps_xx - eps_yy)),   eps = diag(1, -1, 0)

both affine (``z = 0``) and relaxed, plus the 6 x 6 Voigt stiffness (strains ``e_11, e_22,
e_33, 2 e_23, 2 e_13, 2 e_12``; stresses symmetrised) and its orientation averages
``K_iso = C_aabb / 9``, ``mu_iso = (C_abab - C_aabb / 3) / 10`` (invariants of the tensor, equal to
the Voigt averages ``(C11+C22+C33 + 2(C12+C13+C23)) / 9`` and ``(C11+C22+C33 - C12-C13-C23 +
3 (C44+C55+C66)) / 15`` with ``C12`` etc. the mean of the two off-diagonal entries). For the
affine tensor these invariants are sums over the contacts, exactly (``pardem.physics.effective_medium.affine_sums``)::

    K_iso,aff = sum kn r^2 / (9 V) + 2 p / 3,    mu_iso,aff = sum (2 kn + 3 kt) r^2 / (30 V) - 4 p / 5
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

BULK = -np.eye(3)                           # the protocol's isotropic compression (per unit e)
SHEAR = np.diag([1.0, -1.0, 0.0])           # its volume-preserving shear
# Voigt order of the 6 x 6 stiffness: e_11, e_22, e_33, 2 e_23, 2 e_13, 2 e_12
VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


@dataclass(frozen=True)
class Network:
    """A contact network (see the module docstring). Arrays: ``i, j`` [nc] int grain rows,
    ``d`` [nc, 3] branch vectors i -> j [m], ``fn`` [nc] normal force (repulsive > 0) [N],
    ``kn``, ``kt`` [nc] [N/m], ``li``, ``lj`` [nc] arms [m]; ``n`` grains, ``volume`` [m^3]."""
    n: int
    i: np.ndarray
    j: np.ndarray
    d: np.ndarray
    fn: np.ndarray
    kn: np.ndarray
    kt: np.ndarray
    li: np.ndarray
    lj: np.ndarray
    volume: float

    def __post_init__(self):
        nc = len(self.i)
        for name in ("j", "fn", "kn", "kt", "li", "lj"):
            if len(getattr(self, name)) != nc:
                raise ValueError(f"Network.{name} has {len(getattr(self, name))} rows: expected {nc} "
                                 "(one per contact)")
        if self.d.shape != (nc, 3):
            raise ValueError(f"Network.d must be [{nc}, 3], got {self.d.shape}")
        if nc and (min(self.i.min(), self.j.min()) < 0 or max(self.i.max(), self.j.max()) >= self.n):
            raise ValueError(f"Network.i, j must be grain rows in [0, {self.n})")
        if not self.volume > 0.0:
            raise ValueError(f"Network.volume must be > 0 [m^3], got {self.volume}")

    @property
    def n_contacts(self):
        return len(self.i)

    @property
    def r(self):
        """Centre distances [nc] [m]."""
        return np.sqrt(np.einsum("ij,ij->i", self.d, self.d))

    @property
    def normal(self):
        """Unit normals i -> j [nc, 3]."""
        return self.d / self.r[:, None]

    def stress(self):
        """Love-Weber stress [3, 3] [Pa] of the normal forces (tension positive)."""
        return -np.einsum("c,ca,cb->ab", self.fn / self.r, self.d, self.d) / self.volume

    def pressure(self):
        """``p = -tr(sigma) / 3 = sum fn r / (3 V)`` [Pa]."""
        return float(np.sum(self.fn * self.r) / (3.0 * self.volume))

    def subset(self, contacts):
        """The network of the contacts selected by the mask or index array ``contacts``."""
        c = contacts
        return Network(self.n, self.i[c], self.j[c], self.d[c], self.fn[c], self.kn[c], self.kt[c],
                       self.li[c], self.lj[c], self.volume)


def hertz_mindlin_network(x, radius, cell_length, i, j, shift, e_star, g_star):
    """The ``Network`` of the touching pairs among ``(i, j)`` under the Hertz-Mindlin law.

    x [n, 3] centres [m], radius [n] [m], cell_length [3] edges of the periodic cell [m] (the
    volume), i, j [m] candidate pairs (rows), shift [m, 3] image shift added to ``x_j`` [m];
    e_star, g_star [Pa] the contact moduli (``hertz_mindlin.effective_moduli``). See
    ``hertz_mindlin_branches``.
    """
    x = np.asarray(x, dtype=float)
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)
    d = x[j] - x[i] + np.asarray(shift, dtype=float)
    return hertz_mindlin_branches(len(x), i, j, d, radius, float(np.prod(cell_length)), e_star, g_star)


def hertz_mindlin_branches(n, i, j, d, radius, volume, e_star, g_star):
    """The ``Network`` of the touching pairs ``(i, j)`` (rows of ``n`` grains) of branch vectors
    ``d`` [m, 3] [m] (image included), radii ``radius`` [n] [m], cell volume [m^3]. Per contact
    (``R* = R_i R_j / (R_i + R_j)``, ``a = sqrt(R* delta)``, docs/physics.md section 8):
    ``fn = 4/3 E* a delta``, ``kn = d fn / d delta = 2 E* a``, ``kt = 8 G* a``. Pairs with
    ``delta <= 0`` are left out.
    """
    radius = np.asarray(radius, dtype=float)
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)
    d = np.asarray(d, dtype=float)
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    delta = radius[i] + radius[j] - r
    keep = delta > 0.0
    i, j, d, delta = i[keep], j[keep], d[keep], delta[keep]
    ri, rj = radius[i], radius[j]
    a = np.sqrt(ri * rj / (ri + rj) * delta)
    return Network(int(n), i, j, d, 4.0 / 3.0 * e_star * a * delta, 2.0 * e_star * a, 8.0 * g_star * a,
                   ri - 0.5 * delta, rj - 0.5 * delta, float(volume))


def _cross_matrices(n):
    """[nc, 3, 3] matrices ``[n]x`` with ``[n]x v = n x v``."""
    m = np.zeros((len(n), 3, 3))
    m[:, 0, 1], m[:, 0, 2] = -n[:, 2], n[:, 1]
    m[:, 1, 0], m[:, 1, 2] = n[:, 2], -n[:, 0]
    m[:, 2, 0], m[:, 2, 1] = -n[:, 1], n[:, 0]
    return m


def _operators(net, scale):
    """Per contact: ``b_n`` [nc, 12], ``B_w``, ``B_g`` [nc, 3, 12] mapping the local DOFs
    ``(u_i, phi_i, u_j, phi_j)`` to ``s_n``, ``w``, ``g`` (module docstring), the normals and ``r``."""
    r = net.r
    nrm = net.d / r[:, None]
    P = np.eye(3)[None] - nrm[:, :, None] * nrm[:, None, :]
    X = _cross_matrices(nrm)
    nc = net.n_contacts
    bn = np.zeros((nc, 12))
    bn[:, 0:3], bn[:, 6:9] = -nrm, nrm
    Bw = np.zeros((nc, 3, 12))
    Bw[:, :, 0:3], Bw[:, :, 6:9] = -P, P
    Bw[:, :, 3:6] = X * (net.li / scale)[:, None, None]
    Bw[:, :, 9:12] = X * (net.lj / scale)[:, None, None]
    Bg = np.zeros((nc, 3, 12))
    Bg[:, :, 0:3], Bg[:, :, 6:9] = -P, P
    return bn, Bw, Bg, nrm, r


def _dofs(net):
    k = np.arange(6)
    return np.concatenate([6 * net.i[:, None] + k, 6 * net.j[:, None] + k], axis=1)   # [nc, 12]


def default_scale(net):
    """The rotation scale [m]: the mean arm of the contacts (about the mean radius)."""
    return float(np.mean(np.concatenate([net.li, net.lj]))) if net.n_contacts else 1.0


def stiffness_matrix(net, scale=None):
    """The symmetric stiffness matrix ``H`` [6 n, 6 n] (scipy CSR) [N/m] of the network: the
    generalised force change is ``-H z`` for DOFs ``z = (u_k, scale * theta_k)`` per grain k
    (forces, and torques over ``scale``)."""
    scale = default_scale(net) if scale is None else float(scale)
    bn, Bw, Bg, _, r = _operators(net, scale)
    Kc = (net.kn[:, None, None] * bn[:, :, None] * bn[:, None, :]
          + net.kt[:, None, None] * np.einsum("cki,ckj->cij", Bw, Bw)
          - (net.fn / r)[:, None, None] * np.einsum("cki,ckj->cij", Bg, Bg))
    idx = _dofs(net)
    rows = np.broadcast_to(idx[:, :, None], Kc.shape).ravel()
    cols = np.broadcast_to(idx[:, None, :], Kc.shape).ravel()
    m = 6 * net.n
    return sp.coo_matrix((Kc.ravel(), (rows, cols)), shape=(m, m)).tocsr()


def contact_measures(net, eps=None, u=None, theta=None):
    """``(s_n [nc], w [nc, 3], g [nc, 3], dd [nc, 3])`` of the affine strain ``eps`` [3, 3] and the
    grain translations ``u`` [n, 3] [m] and rotations ``theta`` [n, 3] [rad] (each may be None)."""
    nrm = net.normal
    dd = np.zeros_like(net.d)
    if eps is not None:
        dd += net.d @ np.asarray(eps, dtype=float).T
    if u is not None:
        dd += u[net.j] - u[net.i]
    s_n = np.einsum("ij,ij->i", nrm, dd)
    g = dd - s_n[:, None] * nrm
    w = g.copy()
    if theta is not None:
        c = net.li[:, None] * theta[net.i] + net.lj[:, None] * theta[net.j]
        w += np.cross(nrm, c)
    return s_n, w, g, dd


def contact_increments(net, eps=None, u=None, theta=None):
    """First-order changes of the force on i ``dF_i`` [nc, 3] [N] and of the torques ``dT_i``,
    ``dT_j`` [nc, 3] [N m] of every contact (module docstring), and the ``dd`` [nc, 3] [m]."""
    s_n, w, g, dd = contact_measures(net, eps, u, theta)
    nrm = net.normal
    ft = net.kt[:, None] * w
    dF = net.kn[:, None] * s_n[:, None] * nrm + ft - (net.fn / net.r)[:, None] * g
    nxf = np.cross(nrm, ft)
    return dF, net.li[:, None] * nxf, net.lj[:, None] * nxf, dd


def load_increments(net, eps=None, u=None, theta=None):
    """Per grain force and torque changes ``(dF [n, 3] [N], dT [n, 3] [N m])`` of a displacement
    (the direct per-contact form; ``-H z`` equals it)."""
    dF, dTi, dTj, _ = contact_increments(net, eps, u, theta)
    F = np.zeros((net.n, 3))
    T = np.zeros((net.n, 3))
    np.add.at(F, net.i, dF)
    np.add.at(F, net.j, -dF)
    np.add.at(T, net.i, dTi)
    np.add.at(T, net.j, dTj)
    return F, T


def stress_increment(net, eps=None, u=None, theta=None, stress=None):
    """First-order Love-Weber stress change [3, 3] [Pa] (tension positive, not symmetrised) of the
    affine strain ``eps`` plus the non-affine ``u``, ``theta``; ``stress`` [3, 3] the reference
    stress whose volume factor changes (default: the network's own)."""
    dF, _, _, dd = contact_increments(net, eps, u, theta)
    F = -net.fn[:, None] * net.normal
    ds = (np.einsum("ca,cb->ab", dd, F) + np.einsum("ca,cb->ab", net.d, dF)) / net.volume
    if eps is not None:
        s0 = net.stress() if stress is None else np.asarray(stress, dtype=float)
        ds -= s0 * np.trace(eps)
    return ds


def affine_forces(net, eps, scale=None):
    """The generalised out-of-balance force [6 n] of the affine strain ``eps`` (forces, torques over
    ``scale``): the right-hand side of ``H z = f``."""
    scale = default_scale(net) if scale is None else float(scale)
    F, T = load_increments(net, eps=eps)
    return np.concatenate([F, T / scale], axis=1).ravel()


def backbone(net, min_contacts=2):
    """Mask [n] of the grains kept by the relaxation: grains with fewer than ``min_contacts``
    contacts removed repeatedly (rattlers), then the largest connected cluster; and the mask
    [nc] of the contacts between kept grains."""
    alive = np.ones(net.n, dtype=bool)
    live = np.ones(net.n_contacts, dtype=bool)
    while True:
        deg = np.bincount(net.i[live], minlength=net.n) + np.bincount(net.j[live], minlength=net.n)
        drop = alive & (deg < min_contacts)
        if not drop.any():
            break
        alive &= ~drop
        live &= alive[net.i] & alive[net.j]
    if live.any():
        g = sp.coo_matrix((np.ones(int(live.sum())), (net.i[live], net.j[live])), shape=(net.n, net.n))
        _, label = connected_components(g, directed=False)
        sizes = np.bincount(label[alive], minlength=label.max() + 1)
        alive &= label == np.argmax(sizes)
        live &= alive[net.i] & alive[net.j]
    return alive, live


def refined_solve(A, lu, b, tol=1e-13, max_refine=50):
    """``(x, residual)``: ``A x = b`` by iterative refinement with the factorisation ``lu`` of a
    shifted ``A`` (``A + shift I``): ``x += lu.solve(b - A x)`` until ``|b - A x| / |b| < tol``
    (or ``max_refine`` rounds); the relative residual is returned with ``x``."""
    nb = float(np.linalg.norm(b))
    z = np.zeros_like(b)
    res = 0.0 if nb == 0.0 else 1.0
    for _ in range(max_refine):
        if nb == 0.0:
            break
        r = b - A @ z
        res = float(np.linalg.norm(r)) / nb
        if res < tol:
            break
        z += lu.solve(r)
    return z, res


class Relaxation:
    """The factorised relaxation problem of a network (see the module docstring, steps 1-4).

    ``pin``: the kept grain whose translation is fixed (default the kept grain of lowest row);
    ``reg``: the Tikhonov shift relative to the mean diagonal (factorisation only); ``scale`` [m]:
    the rotation scale. Attributes: ``kept`` [n], ``contacts`` [nc] masks, ``sub`` (the network of
    the kept contacts), ``H`` (its stiffness matrix), ``free`` the solved DOF indices.
    """

    def __init__(self, net, pin=None, reg=1e-10, scale=None, min_contacts=2):
        self.net = net
        self.scale = default_scale(net) if scale is None else float(scale)
        self.kept, self.contacts = backbone(net, min_contacts)
        if not self.kept.any():
            raise ValueError("linear_response: no grain has two contacts (no backbone to relax)")
        self.sub = net.subset(self.contacts)
        self.H = stiffness_matrix(self.sub, self.scale)
        rows = np.nonzero(self.kept)[0]
        self.pin = int(rows[0]) if pin is None else int(pin)
        if not self.kept[self.pin]:
            raise ValueError(f"linear_response: pin = {self.pin} is not a grain of the backbone")
        dof = (6 * rows[:, None] + np.arange(6)).ravel()
        self.free = dof[~np.isin(dof, 6 * self.pin + np.arange(3))]
        self.Hf = self.H[self.free][:, self.free].tocsc()
        diag = self.Hf.diagonal()
        self.shift = float(reg * np.mean(diag))
        self.lu = splu((self.Hf + self.shift * sp.identity(len(self.free), format="csc")).tocsc())

    def solve(self, f, tol=1e-13, max_refine=50):
        """``z`` [6 n] solving ``H z = f`` on the free DOFs (zeros elsewhere), and the relative
        residual ``|H z - f| / |f|`` on them (iterative refinement to ``tol``)."""
        z, res = refined_solve(self.Hf, self.lu, np.asarray(f, dtype=float)[self.free], tol, max_refine)
        full = np.zeros(6 * self.net.n)
        full[self.free] = z
        return full, res

    def split(self, z):
        """``(u [n, 3] [m], theta [n, 3] [rad])`` of a DOF vector."""
        zz = z.reshape(self.net.n, 6)
        return zz[:, :3].copy(), zz[:, 3:] / self.scale

    def response(self, eps, stress=None):
        """The relaxed response to the affine strain ``eps`` [3, 3]: dict with ``u``, ``theta``
        (non-affine displacements per unit strain), ``affine`` and ``relaxed`` stress increments
        [3, 3] [Pa], ``residual``."""
        eps = np.asarray(eps, dtype=float)
        s0 = self.net.stress() if stress is None else stress
        z, res = self.solve(affine_forces(self.sub, eps, self.scale))
        u, th = self.split(z)
        return {"u": u, "theta": th, "residual": res,
                "affine": stress_increment(self.net, eps, stress=s0),
                "relaxed": stress_increment(self.sub, eps, u, th, stress=s0)}

    def equilibrium_correction(self, force, torque, stress=None):
        """Stress change [3, 3] [Pa] that bringing the unbalanced loads ``force``, ``torque`` [n, 3]
        [N, N m] of a nearly static state to zero would make (solves ``H z = f``): the error of
        a stress measured at that residual. Returns ``(dsigma, residual)``."""
        f = np.concatenate([np.asarray(force, dtype=float), np.asarray(torque, dtype=float) / self.scale],
                           axis=1).ravel()
        z, res = self.solve(f)
        u, th = self.split(z)
        return stress_increment(self.sub, None, u, th), res


def bulk_from(ds, eps=BULK):
    """``K = d p / (-tr eps)`` [Pa] from a stress increment ``ds`` [3, 3] of the strain ``eps``."""
    return float(np.trace(ds) / (3.0 * np.trace(eps)))


def shear_from(ds, eps=SHEAR):
    """``mu = (ds_xx - ds_yy) / (2 (eps_xx - eps_yy))`` [Pa]."""
    return float((ds[0, 0] - ds[1, 1]) / (2.0 * (eps[0, 0] - eps[1, 1])))


def voigt_strain(k):
    """The unit strain [3, 3] of Voigt component k (shears: engineering strain 1)."""
    a, b = VOIGT[k]
    e = np.zeros((3, 3))
    if a == b:
        e[a, a] = 1.0
    else:
        e[a, b] = e[b, a] = 0.5
    return e


def voigt_stress(s):
    """The Voigt vector [6] of the symmetric part of ``s`` [3, 3]."""
    s = 0.5 * (s + s.T)
    return np.array([s[a, b] for a, b in VOIGT])


def isotropic_averages(C):
    """``(K_iso, mu_iso)`` [Pa]: orientation (Voigt) averages of a 6 x 6 stiffness [Pa], i.e. the
    invariants ``C_aabb / 9`` and ``(C_abab - C_aabb / 3) / 10`` (the pre-stress makes ``C`` not
    quite symmetric, so both off-diagonal halves are used)."""
    C = np.asarray(C)
    diag = C[0, 0] + C[1, 1] + C[2, 2]
    off = float(np.sum(C[:3, :3]) - diag)
    K = (diag + off) / 9.0
    mu = (diag - 0.5 * off + 3.0 * (C[3, 3] + C[4, 4] + C[5, 5])) / 15.0
    return float(K), float(mu)


def moduli(net, stress=None, friction=None, strain=None, full=True, **relax_options):
    """Affine and relaxed moduli of the network [Pa] (module docstring).

    stress [3, 3]: the reference stress for the volume term (default the network's); friction,
    strain: with both, also the fraction of backbone contacts whose linear tangential force at the
    strain amplitude ``strain`` exceeds the Coulomb cap ``friction * fn`` in the relaxed bulk and
    shear responses (the no-slip solution is then not exactly the frictional one there);
    full: also the 6 x 6 stiffnesses and their isotropic averages; ``relax_options`` go to
    ``Relaxation``. Returns a dict (JSON friendly).
    """
    rel = Relaxation(net, **relax_options)
    s0 = net.stress() if stress is None else np.asarray(stress, dtype=float)
    out = {"n_grains": int(net.n), "n_contacts": int(net.n_contacts), "backbone_grains": int(rel.kept.sum()),
           "backbone_contacts": int(rel.contacts.sum()), "pin": rel.pin, "shift": rel.shift,
           "pressure": float(-np.trace(s0) / 3.0)}
    res = []
    for name, eps, fn in (("K", BULK, bulk_from), ("mu", SHEAR, shear_from)):
        r = rel.response(eps, s0)
        out[f"{name}_affine"] = fn(r["affine"], eps)
        out[f"{name}_relaxed"] = fn(r["relaxed"], eps)
        res.append(r["residual"])
        if friction is not None and strain is not None:
            _, w, _, _ = contact_measures(rel.sub, eps, r["u"], r["theta"])
            ft = rel.sub.kt * np.sqrt(np.einsum("ij,ij->i", w, w)) * abs(float(strain))
            out[f"{name}_sliding_fraction"] = float(np.mean(ft > float(friction) * rel.sub.fn))
    if full:
        Ca, Cr = np.zeros((6, 6)), np.zeros((6, 6))
        for k in range(6):
            r = rel.response(voigt_strain(k), s0)
            Ca[:, k] = voigt_stress(r["affine"])
            Cr[:, k] = voigt_stress(r["relaxed"])
            res.append(r["residual"])
        out["C_affine"], out["C_relaxed"] = Ca.tolist(), Cr.tolist()
        out["K_iso_affine"], out["mu_iso_affine"] = isotropic_averages(Ca)
        out["K_iso_relaxed"], out["mu_iso_relaxed"] = isotropic_averages(Cr)
    out["residual"] = float(max(res))
    return out


def protocol_moduli(n, i, j, d, radius, volume, stress, e_star, g_star, strain, modes=None, **relax_options):
    """The isotropic protocol's secant moduli [Pa] for its finite strain ``strain`` = e, to second
    order, from the static response (no dynamics): each increment's secant is the mean of the
    tangent moduli at its start and at its end (trapezoid rule, error O(e^2)), the end state being
    the start moved by e times the linear response (branch vectors ``d + e (eps d + u_j - u_i)``,
    Hertz forces re-evaluated, contacts that open left out), and the shear starts from the end of
    the bulk increment, as in the protocol. Arguments as ``hertz_mindlin_branches`` (all listed
    pairs, touching or not), ``stress`` [3, 3] the reference stress [Pa]. Returns a dict with
    ``K_affine, K_relaxed, mu_affine, mu_relaxed`` and the tangents at both ends
    (``K_relaxed_tangents`` ...). ``modes``: the increments ``(name, eps [3, 3], modulus
    function)`` in order (default the 3D protocol's bulk then shear).
    """
    e = float(strain)
    modes = (("K", BULK, bulk_from), ("mu", SHEAR, shear_from)) if modes is None else modes
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)

    def tangent(dd, vol, s, eps):
        net = hertz_mindlin_branches(n, i, j, dd, radius, vol, e_star, g_star)
        r = Relaxation(net, **relax_options).response(eps, s)
        u = r["u"]
        d2 = dd + e * (dd @ eps.T + u[j] - u[i])
        return r, d2, vol * (1.0 + e * np.trace(eps)), s + e * r["relaxed"]

    out = {}
    dd, vol, s = np.asarray(d, dtype=float), float(volume), np.asarray(stress, dtype=float)
    for name, eps, fn in modes:
        r0, d1, v1, s1 = tangent(dd, vol, s, eps)
        r1, _, _, _ = tangent(d1, v1, s1, eps)
        for kind in ("affine", "relaxed"):
            t = [fn(r0[kind], eps), fn(r1[kind], eps)]
            out[f"{name}_{kind}"] = 0.5 * (t[0] + t[1])
            out[f"{name}_{kind}_tangents"] = t
        dd, vol, s = d1, v1, s1           # the shear starts where the bulk increment ended
    return out


# ---------------------------------------------------------------------------------------------
# the static response to loads on grains, under boundary conditions

PLANE_HELD = (2, 3, 4)      # the DOFs a 2D packing holds: u_z, theta_x, theta_y


def anchored_backbone(net, held, ties=(), min_contacts=2):
    """Masks ``(kept [n], contacts [nc])`` of the grains and contacts of the static response:
    grains with no held DOF and fewer than ``min_contacts`` contacts removed repeatedly (a grain
    held by one contact rolls about it at no force: a zero mode; a grain with a held DOF is never
    removed, its contact fixes what the support leaves free), then only the connected clusters
    (contacts, and the grains of each tie joined) holding an anchor, a grain all of whose six DOFs
    are held (any other cluster is free to move as a body at no force). ``held`` [n, 6] bool."""
    held = np.asarray(held, dtype=bool)
    pinned = held.any(axis=1)
    alive = np.ones(net.n, dtype=bool)
    live = np.ones(net.n_contacts, dtype=bool)
    while True:
        deg = np.bincount(net.i[live], minlength=net.n) + np.bincount(net.j[live], minlength=net.n)
        drop = alive & ~pinned & (deg < min_contacts)
        if not drop.any():
            break
        alive &= ~drop
        live &= alive[net.i] & alive[net.j]
    a = [net.i[live]]
    b = [net.j[live]]
    for grains, _ in ties:
        g = np.asarray(grains, dtype=np.int64)
        a.append(g[:-1])
        b.append(g[1:])
    a, b = np.concatenate(a), np.concatenate(b)
    graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(net.n, net.n))
    _, label = connected_components(graph, directed=False)
    anchored = np.unique(label[held.all(axis=1)])
    alive &= np.isin(label, anchored)
    live &= alive[net.i] & alive[net.j]
    return alive, live


class StaticResponse:
    """The static linear response of a contact network held by supports to loads on its grains:
    normal and tangential springs of every contact (``stiffness_matrix``: no sliding, no opening,
    the reference tangential forces taken as zero, see the module docstring), one sparse solve.

    held [n, 6] bool: the DOFs held at zero (translations x, y, z, rotations x, y, z of each grain;
    a 2D packing holds ``PLANE_HELD`` of every grain); ties: ``(grains [k], dof)`` pairs, DOF
    ``dof`` (not held) of the grains moving as one (a rigid row; the load on it is the sum of its
    grains' loads). Zero modes: rattlers and unanchored clusters are removed
    (``anchored_backbone``); what remains singular is handled as in ``Relaxation`` (step 4: a
    Tikhonov shift ``reg`` in the factorisation only, iterative refinement with the unshifted
    matrix), and ``solve`` reports the relative residual. ``scale`` [m]: the rotation scale.
    Attributes: ``kept`` [n], ``contacts`` [nc] masks, ``sub`` (the kept contacts' network),
    ``T`` [6 n, m] (the reduced coordinates ``q``: DOFs ``z = T q``), ``K`` [m, m] (``T^T H T``).
    """

    def __init__(self, net, held, ties=(), scale=None, reg=1e-10, min_contacts=2):
        held = np.asarray(held, dtype=bool)
        if held.shape != (net.n, 6):
            raise ValueError(f"StaticResponse: held must be [{net.n}, 6] bool, got shape {held.shape}")
        ties = [(np.asarray(g, dtype=np.int64), int(k)) for g, k in ties]
        for g, k in ties:
            if not 0 <= k < 6 or len(g) == 0 or g.min() < 0 or g.max() >= net.n or held[g, k].any():
                raise ValueError(f"StaticResponse: a tie must name grains in [0, {net.n}) and a DOF in [0, 6) "
                                 "that none of them holds")
        if not held.all(axis=1).any():
            raise ValueError("StaticResponse: no grain has all its DOFs held (no anchor: the network is free)")
        self.net, self.held = net, held
        self.scale = default_scale(net) if scale is None else float(scale)
        self.kept, self.contacts = anchored_backbone(net, held, ties, min_contacts)
        self.sub = net.subset(self.contacts)
        H = stiffness_matrix(self.sub, self.scale)
        free = self.kept[:, None] & ~held
        col = -np.ones((net.n, 6), dtype=np.int64)
        m = 0
        for g, k in ties:
            g = g[self.kept[g]]
            if len(g):
                col[g, k] = m
                free[g, k] = False
                m += 1
        idx = np.nonzero(free.ravel())[0]
        col.ravel()[idx] = m + np.arange(len(idx))
        m += len(idx)
        rows = np.nonzero(col.ravel() >= 0)[0]
        self.T = sp.csr_matrix((np.ones(len(rows)), (rows, col.ravel()[rows])), shape=(6 * net.n, m))
        self.K = (self.T.T @ H @ self.T).tocsc()
        self.H = H
        self.shift = float(reg * np.mean(self.K.diagonal())) if m else 0.0
        self.lu = splu((self.K + self.shift * sp.identity(m, format="csc")).tocsc()) if m else None

    def loads(self, force, torque=None):
        """The generalised load [6 n] of per-grain forces [n, 3] [N] and torques [n, 3] [N m]."""
        force = np.asarray(force, dtype=float)
        torque = np.zeros_like(force) if torque is None else np.asarray(torque, dtype=float)
        if force.shape != (self.net.n, 3) or torque.shape != (self.net.n, 3):
            raise ValueError(f"StaticResponse: force and torque must be [{self.net.n}, 3]")
        return np.concatenate([force, torque / self.scale], axis=1).ravel()

    def solve(self, force, torque=None, tol=1e-12, max_refine=50):
        """The response to the loads ``force`` [n, 3] [N] and ``torque`` [n, 3] [N m] (added to the
        reference state's): dict with ``u`` [n, 3] [m], ``theta`` [n, 3] [rad] per grain (zero on
        removed grains), per contact of the network the changes ``force`` [nc, 3] [N] of the force
        on i, ``torque_i``, ``torque_j`` [nc, 3] [N m] (zero on removed contacts), the supports'
        reactions ``reaction_force`` [n, 3] [N], ``reaction_torque`` [n, 3] [N m] (what the held
        DOFs and ties add to the grains at equilibrium) and the relative ``residual``. A load on a
        removed grain's free DOF is refused (ValueError: the response would be undefined)."""
        f = self.loads(force, torque)
        lost = (~self.kept[:, None] & ~self.held).ravel() & (f != 0.0)
        if lost.any():
            g = int(np.nonzero(lost)[0][0] // 6)
            raise ValueError(f"StaticResponse: grain {g} is loaded but is a rattler or not connected to a "
                             "support (no static response)")
        if self.lu is None:
            q, res = np.zeros(0), 0.0
        else:
            q, res = refined_solve(self.K, self.lu, self.T.T @ f, tol, max_refine)
        z = self.T @ q
        zz = z.reshape(self.net.n, 6)
        u, theta = zz[:, :3].copy(), zz[:, 3:] / self.scale
        dF, dTi, dTj, _ = contact_increments(self.sub, u=u, theta=theta)
        out = {"u": u, "theta": theta, "residual": res}
        for name, v in (("force", dF), ("torque_i", dTi), ("torque_j", dTj)):
            full = np.zeros((self.net.n_contacts, 3))
            full[self.contacts] = v
            out[name] = full
        r = (self.H @ z - f).reshape(self.net.n, 6)
        out["reaction_force"], out["reaction_torque"] = r[:, :3], r[:, 3:] * self.scale
        return out


def contact_network(n, gid_i, gid_j, normal, arm_i, arm_j, radius, volume, e_star, g_star):
    """The Hertz-Mindlin ``Network`` of a contact table (rows = gids ``0 .. n - 1``): unit normals
    [nc, 3] i -> j and arms [nc] [m] (``arm_i + arm_j`` = the centre distance, the engine's
    convention), radii [n] [m], volume [m^3], moduli [Pa] (``hertz_mindlin_branches``)."""
    d = np.asarray(normal, dtype=float) * (np.asarray(arm_i, dtype=float) + np.asarray(arm_j, dtype=float))[:, None]
    return hertz_mindlin_branches(n, gid_i, gid_j, d, radius, volume, e_star, g_star)


def at_coulomb_limit(normal, force, friction, margin=1e-9):
    """Mask [nc] of the contacts whose tangential force is at the Coulomb limit: ``|ft| >= (1 -
    margin) mu fn`` with ``fn = -F . n > 0`` and ``ft = F + fn n`` (``force`` [nc, 3] [N] on i,
    ``normal`` [nc, 3] i -> j; the kernel caps ``|ft|`` at ``mu fn`` exactly, to round-off)."""
    n = np.asarray(normal, dtype=float)
    F = np.asarray(force, dtype=float)
    fn = -np.einsum("ij,ij->i", F, n)
    ft = F + fn[:, None] * n
    return (fn > 0.0) & (np.sqrt(np.einsum("ij,ij->i", ft, ft)) >= (1.0 - margin) * float(friction) * fn)


def pair_keys(gid_i, gid_j):
    """int64 keys [nc] of gid pairs (``gid_i < gid_j < 2^31``)."""
    return np.asarray(gid_i, dtype=np.int64) * (np.int64(1) << np.int64(31)) + np.asarray(gid_j, dtype=np.int64)


def state_changes(reference, current, friction):
    """Contacts that changed state between two contact tables (dicts with ``gid_i``, ``gid_j``
    [nc], ``normal`` [nc, 3], ``force`` [nc, 3] [N] on i): ``opened`` (in the reference, not
    touching now), ``closed`` (touching now only), ``at_limit_reference``, ``at_limit_current``
    (at the Coulomb limit ``friction``, ``at_coulomb_limit``) and ``new_at_limit`` (at it now, not
    in the reference), counts; and ``new_at_limit_keys`` (``pair_keys``) of the last."""
    k0 = pair_keys(reference["gid_i"], reference["gid_j"])
    k1 = pair_keys(current["gid_i"], current["gid_j"])
    l0 = at_coulomb_limit(reference["normal"], reference["force"], friction)
    l1 = at_coulomb_limit(current["normal"], current["force"], friction)
    new = np.setdiff1d(k1[l1], k0[l0])
    return {"opened": int(np.setdiff1d(k0, k1).size), "closed": int(np.setdiff1d(k1, k0).size),
            "at_limit_reference": int(l0.sum()), "at_limit_current": int(l1.sum()),
            "new_at_limit": int(new.size), "new_at_limit_keys": new}
