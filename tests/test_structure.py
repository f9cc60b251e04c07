"""Structure measures (pardem.physics.structure) against analytic values and independent computations.

Bond order: perfect crystals in periodic boxes against the tabulated Steinhardt values and against
the addition theorem ``Q_l^2 = (1/N_b^2) sum_{b,b'} P_l(u_b . u_b')`` evaluated with NumPy's Legendre
polynomials (no spherical harmonics involved); the normalised associated Legendre functions against
closed forms and the addition theorem. Hexatic order: triangular and square lattices. g(r): an
ideal gas within its exact binomial error, and pair counts against brute force. Fabric: random
normals (isotropic and with a known second-order anisotropy) within their sampling error. Overlaps:
segment formula against Monte Carlo and the small-overlap asymptote. Rattlers: hand-built networks
and random graphs against a naive iterative removal. Bidisperse: analytic conversions and round trips.
"""
import math

import numpy as np
import pytest
from numpy.polynomial import legendre as npleg

from pardem.physics import structure as st

# -- lattices (independent of the module) ---------------------------------------------------------

FCC = [[0, 0, 0], [.5, .5, 0], [.5, 0, .5], [0, .5, .5]]
BCC = [[0, 0, 0], [.5, .5, .5]]
SC = [[0, 0, 0]]


def cubic(basis, n):
    """Positions of an n x n x n cubic lattice of unit cell 1 with ``basis``, and the box."""
    g = np.array([[i, j, k] for i in range(n) for j in range(n) for k in range(n)], float)
    return (g[:, None, :] + np.asarray(basis, float)[None]).reshape(-1, 3), np.full(3, float(n))


def hcp(nx, ny, nz):
    """Ideal HCP (nearest distance 1) in an orthorhombic cell (1, sqrt 3, 2 sqrt(2/3)) of 4 sites."""
    s3, c = math.sqrt(3.0), 2.0 * math.sqrt(2.0 / 3.0)
    basis = np.array([[0, 0, 0], [.5, s3 / 2, 0], [.5, s3 / 6, c / 2], [0, 2 * s3 / 3, c / 2]])
    cell = np.array([1.0, s3, c])
    g = np.array([[i, j, k] for i in range(nx) for j in range(ny) for k in range(nz)], float)
    return ((g[:, None, :] * cell + basis[None]).reshape(-1, 3), cell * [nx, ny, nz])


def triangular(nx, ny, a=1.0):
    """Triangular lattice of spacing a, ny even rows, periodic box (nx a, ny a sqrt(3)/2)."""
    x = np.array([[(i + 0.5 * (j % 2)) * a, j * a * math.sqrt(3) / 2, 0.0]
                  for i in range(nx) for j in range(ny)])
    return x, np.array([nx * a, ny * a * math.sqrt(3) / 2, 0.0])


def addition_theorem_Q(i, j, branch, l):
    """Global Q_l from the addition theorem over all ordered bond pairs (both ends of each pair)."""
    u = branch / np.linalg.norm(branch, axis=1)[:, None]
    bonds = np.concatenate([u, -u])            # bonds of i and of j
    c = np.clip(bonds @ bonds.T, -1.0, 1.0)
    return math.sqrt(npleg.legval(c, [0] * l + [1]).sum()) / len(bonds)


# -- Steinhardt order ------------------------------------------------------------------------------

# Tabulated values (Steinhardt, Nelson & Ronchetti 1983; Mickel et al. 2013), quoted to 5 decimals:
# tolerance 5e-6 covers the rounding of the quoted digits. BCC with its first shell of 8 gives
# Q4 = 0.50918, Q6 = 0.62854 (analytic below); Q6 = 0.51069 and Q4 = 0.03637 are those of BCC with
# its first two shells (8 + 6 = 14 neighbours).
CRYSTALS = [
    ("fcc", lambda: cubic(FCC, 3), 0.85, 12, {4: 0.19094, 6: 0.57452}),
    ("hcp", lambda: hcp(5, 3, 3), 1.2, 12, {4: 0.09722, 6: 0.48476}),
    ("bcc8", lambda: cubic(BCC, 4), 0.93, 8, {4: 0.50918, 6: 0.62854}),
    ("bcc14", lambda: cubic(BCC, 4), 1.2, 14, {4: 0.03637, 6: 0.51069}),
    ("sc", lambda: cubic(SC, 5), 1.2, 6, {4: 0.76376, 6: 0.35355}),
]


@pytest.mark.parametrize("name, build, cutoff, nn, ref", CRYSTALS, ids=[c[0] for c in CRYSTALS])
def test_steinhardt_perfect_crystals(name, build, cutoff, nn, ref):
    x, box = build()
    i, j, b = st.neighbour_pairs(x, cutoff, box)
    assert 2 * len(i) == nn * len(x)   # every site has its full shell (the cutoff is right)
    for l, q_ref in ref.items():
        q, Q = st.steinhardt(len(x), i, j, b, l)
        assert abs(Q - q_ref) < 5e-6, (name, l, Q)
        # every site of a perfect crystal is equivalent: per-grain = global (round-off)
        np.testing.assert_allclose(q, Q, rtol=1e-12)
        if len(i) <= 2000:   # independent: addition theorem with NumPy's P_l, round-off only
            assert abs(Q - addition_theorem_Q(i, j, b, l)) < 1e-12


def test_bcc_first_shell_analytic():
    """Q_l^2 of the 8 cube diagonals by the addition theorem: each bond has 1 parallel, 1
    antiparallel, 3 at cos = 1/3 and 3 at cos = -1/3: Q_l^2 = (2 + 3 P_l(1/3) + 3 P_l(-1/3)) / 8."""
    x, box = cubic(BCC, 3)
    i, j, b = st.neighbour_pairs(x, 0.93, box)
    for l in (4, 6):
        P = lambda c: npleg.legval(c, [0] * l + [1])
        expected = math.sqrt((2 + 3 * P(1 / 3) + 3 * P(-1 / 3)) / 8)
        assert abs(st.steinhardt(len(x), i, j, b, l)[1] - expected) < 1e-12   # round-off


def test_steinhardt_rotation_invariant_and_gas():
    """Q_l and q_l are rotation invariant (the FCC bonds rotated by a random orthogonal matrix)."""
    x, box = cubic(FCC, 3)
    rng = np.random.default_rng(3)
    A = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    i, j, b = st.neighbour_pairs(x, 0.85, box)
    q0, Q0 = st.steinhardt(len(x), i, j, b, 6)
    q1, Q1 = st.steinhardt(len(x), i, j, b @ A.T, 6)
    assert abs(Q1 - Q0) < 1e-12 and np.allclose(q1, q0, atol=1e-12)   # round-off
    # a grain without neighbours gets NaN; a single bond gives q_l = 1 (one direction)
    q, Q = st.steinhardt(3, [0], [1], [[0.3, -0.2, 0.9]], 6)
    assert np.isnan(q[2]) and abs(q[0] - 1) < 1e-12 and abs(Q - 1) < 1e-12


def test_normalised_legendre():
    """Against closed forms and the addition theorem sum_m |Y_lm|^2 = (2l+1) / (4 pi)."""
    xs = np.linspace(-1, 1, 41)
    for x in xs:
        s = math.sqrt(max(0.0, 1 - x * x))
        assert abs(st.legendre_normalised(2, 2, x) - 0.25 * math.sqrt(15 / (2 * math.pi)) * s * s) < 1e-14
        assert abs(st.legendre_normalised(3, 1, x)
                   + 0.125 * math.sqrt(21 / math.pi) * s * (5 * x * x - 1)) < 1e-14
        for l in range(0, 9):
            y0 = math.sqrt((2 * l + 1) / (4 * math.pi)) * npleg.legval(x, [0] * l + [1])
            assert abs(st.legendre_normalised(l, 0, x) - y0) < 1e-13
            tot = st.legendre_normalised(l, 0, x) ** 2 + 2 * sum(
                st.legendre_normalised(l, m, x) ** 2 for m in range(1, l + 1))
            assert abs(tot - (2 * l + 1) / (4 * math.pi)) < 1e-13   # round-off of ~10 terms


# -- hexatic order ---------------------------------------------------------------------------------

def test_hexatic_triangular_and_square():
    x, box = triangular(8, 8)
    i, j, b = st.neighbour_pairs(x, 1.2, box, dim=2)
    assert 2 * len(i) == 6 * len(x)
    psi, glob, mod = st.hexatic_order(len(x), i, j, b)
    assert abs(glob - 1) < 1e-12 and np.allclose(np.abs(psi), 1, atol=1e-12)   # round-off
    # square lattice: bonds at 0, 90, 180, 270 deg, sum of exp(6 i theta) = 1 - 1 + 1 - 1 = 0
    g = np.array([[i_, j_, 0.0] for i_ in range(8) for j_ in range(8)])
    i, j, b = st.neighbour_pairs(g, 1.2, [8, 8], dim=2)
    psi, glob, mod = st.hexatic_order(len(g), i, j, b)
    assert glob < 1e-12 and np.abs(psi).max() < 1e-12
    psi4, glob4, _ = st.hexatic_order(len(g), i, j, b, m=4)
    assert abs(glob4 - 1) < 1e-12 and np.allclose(psi4, 1, atol=1e-12)


def test_hexatic_rotated_patch_phase():
    """A rotated finite triangular patch: every bond angle is alpha mod 60 deg, so every grain
    (edge grains too) has psi_6 = exp(6 i alpha) exactly (round-off)."""
    x, _ = triangular(6, 6)
    a = 0.3
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    i, j, b = st.neighbour_pairs(x @ R.T, 1.2, None, dim=2)
    psi, glob, _ = st.hexatic_order(len(x), i, j, b)
    assert np.allclose(psi, np.exp(6j * a), atol=1e-12) and abs(glob - 1) < 1e-12


# -- pair distribution -----------------------------------------------------------------------------

@pytest.mark.parametrize("dim", [2, 3])
def test_gr_ideal_gas(dim):
    """Uniform points in a periodic box. Per bin the pair count is a sum over the C(N,2) pairs of
    indicators with p_b = shell_b / V; two pairs sharing a point are independent (given x_i, the
    displacements to x_j and x_k are independent and uniform on the torus), so its variance is
    exactly C(N,2) p_b (1 - p_b): sigma(g_b) = sqrt((1 - p_b) / (C(N,2) p_b)). Tests: every bin
    within 5 sigma (50 bins: false alarm ~3e-5), and chi^2 / n_bins within 5 sqrt(2 / n_bins) of 1."""
    rng = np.random.default_rng(11 + dim)
    n, L = 1500, np.array([1.0, 1.3, 0.9])[:dim]
    x = np.zeros((n, 3))
    x[:, :dim] = rng.uniform(0, L, size=(n, dim))
    out = st.pair_distribution(x, L, r_max=0.45, n_bins=50, dim=dim)
    V = np.prod(L)
    shell = np.pi * np.diff(out["edges"] ** 2) if dim == 2 else 4 / 3 * np.pi * np.diff(out["edges"] ** 3)
    p = shell / V
    npairs = n * (n - 1) / 2
    np.testing.assert_allclose(out["expected"], npairs * p, rtol=1e-12)
    sigma = np.sqrt((1 - p) / (npairs * p))
    z = (out["g"] - 1) / sigma
    assert np.abs(z).max() < 5, np.abs(z).max()
    chi2 = np.mean(z ** 2)
    assert abs(chi2 - 1) < 5 * math.sqrt(2 / 50), chi2


@pytest.mark.parametrize("dim", [2, 3])
def test_gr_counts_brute_force_and_partials(dim):
    rng = np.random.default_rng(5)
    n, L = 300, np.array([2.0, 2.5, 3.0])[:dim]
    x = np.zeros((n, 3))
    x[:, :dim] = rng.uniform(-L, 2 * L, size=(n, dim))   # unwrapped positions
    species = rng.integers(0, 2, n)
    out = st.pair_distribution(x, L, r_max=1.0, n_bins=20, dim=dim, species=species)
    d = x[:, None, :dim] - x[None, :, :dim]
    d -= np.round(d / L) * L
    r = np.sqrt((d ** 2).sum(-1))[np.triu_indices(n, 1)]
    np.testing.assert_array_equal(out["counts"], np.histogram(r, bins=out["edges"])[0])
    # partial counts add up to the total: sum_ab g_ab * (ideal count of ab) = counts
    na = np.bincount(species)
    tot = np.zeros(20)
    for (a, b), g in out["partial"].items():
        m = na[a] * (na[a] - 1) / 2 if a == b else na[a] * na[b]
        tot += g * m * out["expected"] / (n * (n - 1) / 2)
    np.testing.assert_allclose(tot, out["counts"], rtol=1e-10, atol=1e-9)


def test_gr_fcc_first_shell():
    """FCC: 12 neighbours at 1/sqrt(2): the bin holding that distance counts 6 N pairs, the bins
    below it none."""
    x, box = cubic(FCC, 4)
    out = st.pair_distribution(x, box, r_max=1.0, n_bins=100)
    k = int(np.floor(math.sqrt(0.5) / 0.01))
    assert out["counts"][k] == 6 * len(x) and out["counts"][:k].sum() == 0


# -- fabric ----------------------------------------------------------------------------------------

def random_normals(rng, n, dim):
    v = rng.normal(size=(n, 3))
    if dim == 2:
        v[:, 2] = 0
    return v * rng.uniform(0.5, 2.0, size=(n, 1))   # lengths must not matter


@pytest.mark.parametrize("dim", [2, 3])
def test_fabric_isotropic(dim):
    """<n n> -> I / dim. Sampling sd of a component, n normals: 3D diagonal sqrt((1/5 - 1/9) / n),
    off-diagonal sqrt(1/15 / n); 2D both sqrt(1/8 / n). Tolerance 5 sd."""
    rng = np.random.default_rng(1)
    n = 20000
    F = st.fabric_tensor(random_normals(rng, n, dim), dim)
    assert F.shape == (dim, dim) and abs(np.trace(F) - 1) < 1e-12
    sd_diag = math.sqrt((0.2 - 1 / 9) / n) if dim == 3 else math.sqrt(1 / 8 / n)
    sd_off = math.sqrt(1 / 15 / n) if dim == 3 else math.sqrt(1 / 8 / n)
    dev = np.abs(F - np.eye(dim) / dim)
    assert np.all(np.diag(dev) < 5 * sd_diag) and np.all(dev[~np.eye(dim, dtype=bool)] < 5 * sd_off)
    assert abs(np.trace(st.fabric_deviator(F))) < 1e-12


def test_fabric_anisotropy_2d():
    """Normals drawn from (1 + a cos 2 (theta - theta0)) / 2 pi by rejection: the estimates of
    a cos 2 theta0 = 2 <cos 2 theta> and a sin 2 theta0 = 2 <sin 2 theta> have sd <= sqrt(2 / n);
    tolerance 5 sd on a and 5 sd / a on theta0."""
    rng = np.random.default_rng(2)
    a, t0, n = 0.4, 0.5, 40000   # theta0 = half the angle of the (a cos, a sin) estimate: sd / (2a)
    t = rng.uniform(0, 2 * np.pi, 3 * n)
    t = t[rng.uniform(0, 1 + a, t.size) < 1 + a * np.cos(2 * (t - t0))][:n]
    assert t.size == n
    b = np.stack([np.cos(t), np.sin(t), np.zeros(n)], 1)
    aa, aij, direction = st.fabric_anisotropy(st.fabric_tensor(b, 2))
    sd = math.sqrt(2 / n)
    assert abs(aa - a) < 5 * sd
    ang = math.atan2(direction[1], direction[0]) % np.pi
    assert abs(ang - t0) < 5 * sd / a


def test_fabric_anisotropy_3d():
    """Axisymmetric (1 + a P2(cos theta)) / 4 pi about z: a_zz = 15/2 (<n_z^2> - 1/3) = a, sd of
    the estimate 15/2 sqrt(4/45 / n); tolerance 5 sd (the transverse noise adds a bias of order
    sd^2 / a, negligible). Exact cases: all normals along z give F = diag(0, 0, 1)."""
    rng = np.random.default_rng(4)
    a, n = 0.5, 40000
    v = rng.normal(size=(4 * n, 3))
    u = v / np.linalg.norm(v, axis=1)[:, None]
    w = 1 + a * 0.5 * (3 * u[:, 2] ** 2 - 1)
    u = u[rng.uniform(0, 1 + a, len(u)) < w][:n]
    assert len(u) == n
    aa, aij, direction = st.fabric_anisotropy(st.fabric_tensor(u, 3))
    assert abs(aa - a) < 5 * 7.5 * math.sqrt(4 / 45 / n)
    # tilt of the major axis ~ F_xz / (F_zz - F_xx) = sqrt(1/15 / n) / (a / 5) ~ 0.013 rad (sd);
    # |n_z| > 0.99 allows 0.14 rad, about 10 sd
    assert abs(abs(direction[2]) - 1) < 0.01
    F = st.fabric_tensor([[0, 0, 2.0], [0, 0, -1.0]], 3)
    np.testing.assert_allclose(F, np.diag([0, 0, 1.0]), atol=1e-15)
    # integer weights = repeating the contacts (independent: the unweighted tensor of the
    # repeated list); round-off
    b = u[:50]
    w = np.arange(50) % 3
    np.testing.assert_allclose(st.fabric_tensor(b, 3, w), st.fabric_tensor(np.repeat(b, w, axis=0), 3),
                               atol=1e-14)


# -- overlaps and solid fraction -------------------------------------------------------------------

def test_lens_area_monte_carlo():
    """Two overlapping disks: segment formula against Monte Carlo in the bounding box of the
    lens (binomial sd A_box sqrt(p (1 - p) / N); tolerance 5 sd)."""
    rng = np.random.default_rng(7)
    for r1, r2, d in [(1.0, 0.7, 1.2), (1.0, 1.0, 0.5), (0.5, 1.5, 1.3)]:
        N = 400000
        xmin, xmax = d - r2, r1
        ymax = min(r1, r2)
        p = rng.uniform([xmin, -ymax], [xmax, ymax], size=(N, 2))
        inside = (p[:, 0] ** 2 + p[:, 1] ** 2 < r1 * r1) & ((p[:, 0] - d) ** 2 + p[:, 1] ** 2 < r2 * r2)
        box = (xmax - xmin) * 2 * ymax
        f = inside.mean()
        A = st.lens_area(r1, r2, d)
        assert abs(A - f * box) < 5 * box * math.sqrt(f * (1 - f) / N), (r1, r2, d, A, f * box)


def test_lens_volume_monte_carlo():
    rng = np.random.default_rng(8)
    r1, r2, d, N = 1.0, 0.8, 1.3, 400000
    lo, hi, h = d - r2, r1, min(r1, r2)
    p = rng.uniform([lo, -h, -h], [hi, h, h], size=(N, 3))
    inside = ((p ** 2).sum(1) < r1 * r1) & ((p[:, 0] - d) ** 2 + (p[:, 1:] ** 2).sum(1) < r2 * r2)
    box = (hi - lo) * 4 * h * h
    f = inside.mean()
    assert abs(st.lens_volume(r1, r2, d) - f * box) < 5 * box * math.sqrt(f * (1 - f) / N)


def test_lens_limits():
    """Small overlap delta: area -> (4/3) sqrt(2 R*) delta^1.5 (two parabolic segments), volume ->
    pi R* delta^2, R* = r1 r2 / (r1 + r2), relative corrections O(delta / R) (tolerance 1e-6 at
    delta = 1e-8, which exercises the series branch). Containment and separation: exact."""
    r1, r2 = 1.0, 0.6
    rs = r1 * r2 / (r1 + r2)
    for delta in (1e-8, 1e-6):
        d = r1 + r2 - delta
        assert abs(st.lens_area(r1, r2, d) / (4 / 3 * math.sqrt(2 * rs) * delta ** 1.5) - 1) < 100 * delta + 1e-9
        assert abs(st.lens_volume(r1, r2, d) / (math.pi * rs * delta ** 2) - 1) < 100 * delta + 1e-9
    assert st.lens_area(r1, r2, 1.6) == 0 and st.lens_volume(r1, r2, 2.0) == 0
    assert abs(st.lens_area(r1, r2, 0.3) - math.pi * 0.36) < 1e-15
    assert abs(st.lens_volume(r1, r2, 0.0) - 4 / 3 * math.pi * 0.216) < 1e-15
    # equal disks at d = r sqrt(2): chord through both centres' quarter points, area = r^2 (pi/2 - 1)
    assert abs(st.lens_area(1.0, 1.0, math.sqrt(2)) - (math.pi / 2 - 1)) < 1e-14
    # continuity at the series switch t = 1e-2 (relative 1e-13: series truncation < 1e-15)
    lo, hi = st._segment(1e-2 * (1 - 1e-12)), st._segment(1e-2)
    assert abs(lo / hi - 1) < 1e-10


def test_solid_fraction_2d_3d():
    box = np.array([4.0, 5.0, 6.0])
    x = np.array([[1.0, 1.0, 0.0], [2.2, 1.0, 0.0], [3.0, 4.0, 0.0]])
    r = np.array([0.7, 0.6, 0.5])
    i, j, b = st.overlapping_pairs(x, r, box, dim=2)
    assert list(zip(i, j)) == [(0, 1)]
    phi, raw = st.solid_fraction(r, box, 2, i, j, np.linalg.norm(b, axis=1))
    # exact expressions evaluated differently: round-off (fractions ~0.2, 1e-14 = ~50 ulp)
    assert abs(raw - np.pi * np.sum(r ** 2) / 20) < 1e-14
    assert abs(phi - (np.pi * np.sum(r ** 2) - st.lens_area(0.7, 0.6, 1.2)) / 20) < 1e-14
    # periodic: a pair overlapping only through the x boundary (distance 0.8 across x = 0)
    xs = np.array([[0.2, 1.0, 0.0], [3.4, 1.0, 0.0], [2.0, 4.0, 0.0]])
    i, j, b = st.overlapping_pairs(xs, r, box, dim=2)
    assert len(i) == 1 and abs(np.linalg.norm(b[0]) - 0.8) < 1e-12
    i, j, b = st.overlapping_pairs(xs, r, box, dim=3)
    phi, raw = st.solid_fraction(r, box, 3, i, j, np.linalg.norm(b, axis=1))
    assert abs(phi - (4 / 3 * np.pi * np.sum(r ** 3) - st.lens_volume(0.7, 0.6, 0.8)) / 120) < 1e-14


# -- coordination and rattlers ---------------------------------------------------------------------

def naive_rattlers(n, i, j, k):
    """Independent: remove all grains below k contacts at once, recount, repeat."""
    alive = np.ones(n, bool)
    live = np.ones(len(i), bool)
    while True:
        deg = np.bincount(i[live], minlength=n) + np.bincount(j[live], minlength=n)
        out = alive & (deg < k)
        if not out.any():
            return alive, live
        alive &= ~out
        live &= alive[i] & alive[j]


def test_rattlers_hand_built_3d():
    """K5 (grains 0-4, 4 contacts each) survives. Grain 5 touches 0, 1, 2 (3 < 4: rattler). Grain 6
    touches 0, 1, 2 and 7; grain 7 touches 6, 3, 4 (3: rattler), after which 6 has 3 (rattler, a
    cascade). Grain 8 has no contact. Grain 4 also touches 5 with fn = 0 (not force-carrying).
    Force-carrying contacts: 10 + 3 + 4 + 2 = 19 over N = 9: Z = 38/9; without rattlers 20/5 = 4."""
    k5 = [(a, b) for a in range(5) for b in range(a + 1, 5)]
    pairs = k5 + [(5, 0), (5, 1), (5, 2), (6, 0), (6, 1), (6, 2), (6, 7), (7, 3), (7, 4), (4, 5)]
    i, j = np.array(pairs).T
    fn = np.ones(len(pairs))
    fn[-1] = 0.0
    c = st.coordination(9, i, j, fn, dim=3)
    assert c["n_contacts"] == 19 and abs(c["Z"] - 38 / 9) < 1e-15
    assert abs(c["Z_no_rattlers"] - 4.0) < 1e-15 and c["rattlers"] == 4
    assert abs(c["rattler_fraction"] - 4 / 9) < 1e-15
    np.testing.assert_array_equal(c["alive"], [1, 1, 1, 1, 1, 0, 0, 0, 0])
    np.testing.assert_array_equal(c["kept"], [1] * 10 + [0] * 10)


def test_rattlers_hand_built_2d_lattice():
    """Disks of radius 0.5 (+1e-6) on a unit triangular lattice: a hexagon (centre + 6 ring disks,
    ring disks have 3 contacts) is rigid in 2D (threshold 3). A disk in a pocket of two ring disks
    (2 contacts) is a rattler; a disk touching it and one ring disk (2) is one too."""
    ring = [(math.cos(k * np.pi / 3), math.sin(k * np.pi / 3)) for k in range(6)]
    pocket = (ring[0][0] + ring[1][0], ring[0][1] + ring[1][1])     # touches ring 0 and ring 1
    extra = (2.0, 0.0)                                                # touches pocket and ring 0
    xy = np.array([(0.0, 0.0)] + ring + [pocket, extra])
    assert abs(np.hypot(*(xy[8] - xy[7])) - 1) < 1e-12 and abs(np.hypot(*(xy[8] - xy[1])) - 1) < 1e-12
    x = np.c_[xy, np.zeros(len(xy))]
    i, j, b = st.overlapping_pairs(x, np.full(len(x), 0.5 + 1e-6), None, dim=2)
    assert len(i) == 12 + 2 + 2   # 6 spokes + 6 ring edges + pocket 2 + extra 2
    c = st.coordination(len(x), i, j, dim=2)
    np.testing.assert_array_equal(c["alive"], [1] * 7 + [0, 0])
    assert abs(c["Z_no_rattlers"] - 24 / 7) < 1e-15 and c["rattlers"] == 2


@pytest.mark.parametrize("dim", [2, 3])
def test_rattlers_random_graphs_against_naive(dim):
    rng = np.random.default_rng(9 + dim)
    for trial in range(20):
        n = int(rng.integers(5, 200))
        m = int(rng.integers(0, 3 * n))
        i = rng.integers(0, n, m)
        j = rng.integers(0, n, m)
        keep = i != j
        i, j = i[keep], j[keep]
        fn = rng.uniform(-0.2, 1.0, len(i))
        alive, kept = st.rattlers(n, i, j, fn, dim)
        pos = fn > 0
        a2, l2 = naive_rattlers(n, i[pos], j[pos], dim + 1)
        np.testing.assert_array_equal(alive, a2)
        np.testing.assert_array_equal(kept[pos], l2)
        assert not kept[~pos].any()


# -- force distribution ----------------------------------------------------------------------------

def test_force_distribution():
    d = st.force_distribution([1.0, 2.0, 3.0, 0.0, -1.0])
    assert d["n"] == 3 and d["mean"] == 2.0
    assert abs(d["moments"][2] - 7 / 6) < 1e-15 and abs(d["fraction_above_mean"] - 1 / 3) < 1e-15
    # exponential forces: <y^2> = 2 (sd of the estimate sqrt((24 - 4) / n) with y = f / <f> ...)
    rng = np.random.default_rng(12)
    n = 100000
    d = st.force_distribution(rng.exponential(3.0, n))
    assert abs(d["mean"] - 3.0) < 5 * 3.0 / math.sqrt(n)
    assert abs(d["moments"][2] - 2) < 5 * math.sqrt(20 / n)
    # ... and the histogram against the exponential of scale 3 seen through the sample mean m:
    # P(a m < f < b m) / P(f < 5 m); binomial sd per bin over the n_in forces in range; 5 sd
    e, m = d["edges"], d["mean"]
    cdf = 1 - np.exp(-e * m / 3.0)
    pin = np.diff(cdf) / cdf[-1]
    nin = n * cdf[-1]
    sd = np.sqrt(pin * (1 - pin) / nin) / np.diff(e)
    assert np.all(np.abs(d["density"] - pin / np.diff(e)) < 5 * sd)


# -- bidisperse ------------------------------------------------------------------------------------

@pytest.mark.parametrize("dim", [2, 3])
def test_concentration_round_trip(dim):
    for r in (1.0, 1.4, 2.0, 5.0):
        for x in np.linspace(0, 1, 11):
            c = st.number_to_volume_concentration(x, r, dim)
            assert abs(st.volume_to_number_concentration(c, r, dim) - x) < 1e-14   # round-off
            # independent: the volumes of x small and (1 - x) large grains
            vs, vl = x * 1.0, (1 - x) * r ** dim
            assert abs(c - (vs / (vs + vl) if vs + vl else 0)) < 1e-14


def test_bidisperse_specification():
    """Tolerances 1e-14 / 1e-15: exact relations evaluated in floating point (round-off)."""
    # ratio 2, 3D: equal numbers -> volume concentration 1 / (1 + 8) = 1/9
    b = st.bidisperse(1000, 2.0, 1 / 9, basis="volume", mean_radius=1.5e-4, dim=3)
    assert (b.n_small, b.n_large) == (500, 500)
    assert abs(b.r_large / b.r_small - 2) < 1e-15 and abs(b.radii.mean() / 1.5e-4 - 1) < 1e-14
    assert abs(b.volume_concentration - 1 / 9) < 1e-15
    vol = np.sum(b.radii[:b.n_small] ** 3) / np.sum(b.radii ** 3)
    assert abs(vol - b.volume_concentration) < 1e-14
    # 2D area concentration, large radius given; counts are the nearest integer
    b = st.bidisperse(101, 1.4, 0.5, basis="volume", large_radius=1e-3, dim=2)
    x = 0.5 * 1.96 / (0.5 + 0.5 * 1.96)
    assert b.n_small == round(x * 101) and b.r_large == 1e-3 and abs(b.r_small - 1e-3 / 1.4) < 1e-18
    area = np.sum(b.radii[:b.n_small] ** 2) / np.sum(b.radii ** 2)
    assert abs(area - b.volume_concentration) < 1e-14
    b = st.bidisperse(10, 1.0, 0.0, mean_radius=1.0)
    assert b.n_small == 0 and np.all(b.radii == 1.0)


def test_bad_arguments():
    with pytest.raises(ValueError, match="size_ratio"):
        st.bidisperse(10, 0.5, 0.3, mean_radius=1.0)
    with pytest.raises(ValueError, match="concentration"):
        st.bidisperse(10, 2.0, 1.3, mean_radius=1.0)
    with pytest.raises(ValueError, match="exactly one"):
        st.bidisperse(10, 2.0, 0.3)
    with pytest.raises(ValueError, match="dim"):
        st.fabric_tensor(np.ones((3, 3)), dim=4)
    with pytest.raises(ValueError, match="r_max"):
        st.pair_distribution(np.zeros((4, 3)) + np.arange(4)[:, None] * 0.1, [1, 1, 1], r_max=0.6)
    with pytest.raises(ValueError, match="i == j"):
        st.coordination(3, [0], [0])
