"""Size distributions, regions and random packings (pardem.domains.distributions, regions, packing).

The samples are compared with the requested laws computed independently with scipy (truncated
scipy.stats laws, numerical quadrature of the volume-weighted densities): a Kolmogorov-Smirnov
test for the continuous laws (by number: the sample's CDF; by volume: the number CDF the volume
law implies, and the volume-weighted CDF of the sample), a chi-square test for the discrete ones.
Each test uses a fixed seed; the threshold p > 1e-3 is what a correct sampler passes 999 times in
1000 seeds, while every mutation tried (volume weighting dropped, a wrong truncation) gives
p < 1e-20 at these sample sizes.
"""
import math

import numpy as np
import pytest
from scipy import integrate, stats

from pardem.domains import distributions as D
from pardem.domains import regions as R
from pardem.domains.packing import overlaps, random_pack

N = 20000
P_MIN = 1e-3


def _truncated_cdf(cdf, a, b):
    """CDF of a law of CDF ``cdf`` truncated to [a, b]."""
    lo, hi = cdf(a), cdf(b)
    return lambda r: np.clip((cdf(np.asarray(r)) - lo) / (hi - lo), 0.0, 1.0)


def _quad_cdf(density, a, b):
    """Normalised CDF of ``density`` on [a, b] by adaptive quadrature (independent of the code's
    tabulation), evaluated on the sample points."""
    total = integrate.quad(density, a, b, limit=200, epsabs=0, epsrel=1e-12)[0]

    def cdf(r):
        r = np.atleast_1d(r)
        grid = np.linspace(a, b, 401)
        pieces = [integrate.quad(density, grid[k], grid[k + 1], epsabs=0, epsrel=1e-12)[0] for k in range(400)]
        c = np.concatenate([[0.0], np.cumsum(pieces)]) / total
        # cubic interpolation between 401 exact nodes: error < 1e-9, far below KS resolution
        from scipy.interpolate import CubicSpline
        return np.clip(CubicSpline(grid, c)(r), 0.0, 1.0)
    return cdf


# the requested laws: (distribution, the given density in r (unnormalised), its scipy number CDF)
def _laws():
    a, b = 1e-3, 2e-3
    m, s = 1.5e-3, 0.3e-3
    med, sig = 1e-3, 0.4
    lo_n, hi_n = 0.6e-3, 2.4e-3
    return {
        "uniform": (D.Uniform(a, b), lambda r: 1.0, stats.uniform(a, b - a).cdf, (a, b)),
        "normal": (D.Normal(m, s, lo_n, hi_n), lambda r: stats.norm.pdf(r, m, s),
                   _truncated_cdf(stats.norm(m, s).cdf, lo_n, hi_n), (lo_n, hi_n)),
        "normal_default_cut": (D.Normal(m, s), lambda r: stats.norm.pdf(r, m, s),
                               _truncated_cdf(stats.norm(m, s).cdf, m - 3 * s, m + 3 * s), (m - 3 * s, m + 3 * s)),
        "lognormal": (D.LogNormal(med, sig), lambda r: stats.lognorm.pdf(r, sig, scale=med),
                      _truncated_cdf(stats.lognorm(sig, scale=med).cdf, med * math.exp(-3 * sig),
                                     med * math.exp(3 * sig)),
                      (med * math.exp(-3 * sig), med * math.exp(3 * sig))),
    }


@pytest.mark.parametrize("name", ["uniform", "normal", "normal_default_cut", "lognormal"])
def test_by_number_matches_the_requested_law(name):
    dist, _, cdf, (a, b) = _laws()[name]
    assert dist.by == "number" and (dist.r_min, dist.r_max) == pytest.approx((a, b), rel=1e-15)
    r = dist.sample(N, np.random.default_rng(11))
    assert r.min() >= a and r.max() <= b
    assert stats.kstest(r, cdf).pvalue > P_MIN
    # the code's own CDF agrees with scipy's to the tabulation error (1e-8; 1e-6 allowed)
    grid = np.linspace(a, b, 101)
    assert np.max(np.abs(dist.cdf(grid) - cdf(grid))) < 1e-6


@pytest.mark.parametrize("name", ["uniform", "normal", "lognormal"])
def test_by_volume_matches_the_requested_volume_law(name):
    base, density, vcdf_scipy, (a, b) = _laws()[name]
    kw = {"uniform": lambda: D.Uniform(a, b, by="volume"),
          "normal": lambda: D.Normal(1.5e-3, 0.3e-3, a, b, by="volume"),
          "lognormal": lambda: D.LogNormal(1e-3, 0.4, by="volume")}
    dist = kw[name]()
    r = dist.sample(N, np.random.default_rng(12))
    # (1) the number law a volume law implies: p_N ~ p_V / r^3 (quadrature), KS on the sample
    ncdf = _quad_cdf(lambda x: density(x) / x**3, a, b)
    assert stats.kstest(r, ncdf).pvalue > P_MIN
    # (2) the volume-weighted CDF of the sample against the requested volume CDF: sup distance
    # below 1.95 / sqrt(n_eff) (the Kolmogorov quantile at 0.001 with Kish's effective sample
    # size of the weights r^3; an unweighted sample misses it by ~20 times)
    w = r**3
    order = np.argsort(r)
    emp = np.cumsum(w[order]) / w.sum()
    n_eff = w.sum() ** 2 / np.sum(w**2)
    target = vcdf_scipy(r[order])
    assert np.max(np.abs(emp - target)) < 1.95 / math.sqrt(n_eff)
    # the code's volume CDF is the requested one (to the tabulation)
    grid = np.linspace(a, b, 101)
    assert np.max(np.abs(dist.volume_cdf(grid) - vcdf_scipy(grid))) < 1e-6
    # the mean volume per particle (by number) against the quadrature
    mean_v = integrate.quad(lambda x: density(x) / x**3 * 4 / 3 * math.pi * x**3, a, b, epsrel=1e-12)[0] / \
        integrate.quad(lambda x: density(x) / x**3, a, b, epsrel=1e-12)[0]
    assert dist.mean_volume() == pytest.approx(mean_v, rel=1e-6)


def test_lognormal_by_volume_is_the_hatch_choate_shift():
    # untruncated, a log-normal volume law of median m is a log-normal number law of median
    # m exp(-3 sigma^2) (Hatch and Choate, J. Franklin Inst. 207, 369 (1929)); truncated wide
    # (+-6 sigma of the volume law) the difference is far below the KS resolution
    med, sig = 1e-3, 0.3
    dist = D.LogNormal(med, sig, med * math.exp(-6 * sig), med * math.exp(6 * sig), by="volume")
    r = dist.sample(N, np.random.default_rng(13))
    assert stats.kstest(r, stats.lognorm(sig, scale=med * math.exp(-3 * sig ** 2)).cdf).pvalue > P_MIN


@pytest.mark.parametrize("by", ["number", "volume"])
def test_discrete_fractions(by):
    radii, fractions = np.array([1e-3, 2e-3, 3e-3]), np.array([0.2, 0.5, 0.3])
    dist = D.Discrete(radii, fractions, by=by)
    r = dist.sample(N, np.random.default_rng(14))
    counts = np.array([np.count_nonzero(r == x) for x in radii])
    assert counts.sum() == N                    # only the given sizes
    expected = fractions if by == "number" else (fractions / radii**3) / np.sum(fractions / radii**3)
    assert stats.chisquare(counts, N * expected).pvalue > P_MIN
    # the volume shares of the sample: those requested (by volume) within 3 standard errors
    if by == "volume":
        share = np.array([np.sum(r[r == x] ** 3) for x in radii]) / np.sum(r**3)
        assert np.allclose(share, fractions, atol=0.02)


def test_bidisperse_is_a_two_size_discrete_law():
    d = D.Bidisperse(1e-3, 2e-3, 0.25)
    assert d.radii.tolist() == [1e-3, 2e-3] and d.fractions.tolist() == [0.75, 0.25]
    r = d.sample(N, np.random.default_rng(15))
    assert stats.binomtest(int(np.count_nonzero(r == 2e-3)), N, 0.25).pvalue > P_MIN


@pytest.mark.parametrize("make, message", [
    (lambda: D.Uniform(2e-3, 1e-3), "r_min"),
    (lambda: D.Uniform(0.0, 1e-3), "Uniform.r_min"),
    (lambda: D.Normal(1e-3, 1e-3), "r_min > 0"),
    (lambda: D.LogNormal(1e-3, -1.0), "LogNormal.sigma"),
    (lambda: D.Discrete([1e-3, 1e-3], [0.5, 0.5]), "distinct"),
    (lambda: D.Discrete([1e-3, 2e-3], [0.5, 0.6]), "summing to 1"),
    (lambda: D.Uniform(1e-3, 2e-3, by="mass"), "by = 'mass'"),
])
def test_bad_distributions_are_refused(make, message):
    with pytest.raises(ValueError, match=message):
        make()


# -- regions -----------------------------------------------------------------------------------

REGIONS = {
    "box": R.Box([0.0, -1.0, 2.0], [3.0, 1.0, 3.5]),
    "cylinder_z": R.Cylinder([1.0, 2.0, -1.0], 1.5, 2.0, axis=2),
    "cylinder_x": R.Cylinder([1.0, 2.0, -1.0], 0.5, 4.0, axis=0),
    "sphere": R.Sphere([0.5, 0.5, 0.5], 1.2),
}


@pytest.mark.parametrize("name", list(REGIONS))
def test_region_volume_contains_and_uniform_samples(name):
    reg = REGIONS[name]
    lo, hi = reg.bounds
    rng = np.random.default_rng(3)
    pts = lo + (hi - lo) * rng.random((200000, 3))
    frac = reg.contains(pts).mean()
    # Monte Carlo estimate of the volume: 5 binomial standard errors
    se = math.sqrt(frac * (1 - frac) / len(pts))
    assert abs(frac * np.prod(hi - lo) - reg.volume) <= (5 * se + 1e-12) * np.prod(hi - lo)   # a box: exact
    m = 0.2
    s = reg.sample(20000, rng, margin=m)
    assert np.all(reg.contains(s, margin=m))
    assert not np.all(reg.contains(s, margin=m + 0.1))        # the margin is not larger than asked
    # uniform in the shrunk region: a coordinate whose law is known, KS
    if name == "box":
        u = (s[:, 0] - lo[0] - m) / (hi[0] - lo[0] - 2 * m)
    elif name.startswith("cylinder"):
        plane = [a for a in range(3) if a != reg.axis]
        u = np.sum((s[:, plane] - reg.base[plane]) ** 2, axis=1) / (reg.radius - m) ** 2   # rho^2 uniform
    else:
        u = (np.linalg.norm(s - reg.centre, axis=1) / (reg.radius - m)) ** 3                 # rho^3 uniform
    assert stats.kstest(u, "uniform").pvalue > P_MIN


def test_region_without_room_is_refused():
    with pytest.raises(ValueError, match="no room"):
        R.Cylinder([0, 0, 0], 1.0, 1.0).sample(1, np.random.default_rng(0), margin=0.6)
    with pytest.raises(ValueError, match="Box: hi"):
        R.Box([0, 0, 0], [1, 0, 1])


# -- random packings ---------------------------------------------------------------------------

def _brute_force_min_gap(x, r, y=None, s=None):
    """The smallest surface distance of all pairs of the spheres (x [n, 3], r [n]), or of all pairs
    of one of them and one of (y, s), by brute force (every pair)."""
    other = y is not None
    y, s = (y, s) if other else (x, r)
    d = np.sqrt(np.sum((x[:, None, :] - y[None, :, :]) ** 2, axis=2))
    gap = d - r[:, None] - s[None, :]
    if not other:
        np.fill_diagonal(gap, np.inf)
    return gap.min()


def test_random_pack_places_without_overlap_inside_the_region():
    region = R.Cylinder([0, 0, 0], 10.0, 12.0)
    old = random_pack(R.Box([-8, -8, -3], [8, 8, 2]), D.Uniform(0.8, 1.6), n=150, seed=4)
    cloud = random_pack(region, D.Uniform(0.5, 1.0), volume_fraction=0.2, seed=5,
                        existing=(old.positions, old.radii), gap=0.01)
    assert cloud.complete and cloud.n > 300     # 0.2 V / <v> = 385 spheres
    # new-new and new-old pairs keep the gap (old-old pairs were packed without one)
    assert _brute_force_min_gap(cloud.positions, cloud.radii) >= 0.01 - 1e-12
    assert _brute_force_min_gap(cloud.positions, cloud.radii, old.positions, old.radii) >= 0.01 - 1e-12
    assert _brute_force_min_gap(old.positions, old.radii) < 0.01       # the old ones do not (the check can fail)
    assert np.all(region.contains(cloud.positions, margin=cloud.radii))
    # the target volume: reached by the last sphere drawn, not before
    v = 4 / 3 * math.pi * cloud.radii**3
    assert v.sum() >= 0.2 * region.volume > v.sum() - v.max()
    assert cloud.volume_fraction == pytest.approx(v.sum() / region.volume)


def test_random_pack_is_deterministic_and_keeps_the_distribution():
    region = R.Box([0, 0, 0], [30, 30, 30])
    dist = D.Normal(1.0, 0.15)
    a = random_pack(region, dist, n=1500, seed=9)
    b = random_pack(region, dist, n=1500, seed=9)
    c = random_pack(region, dist, n=1500, seed=10)
    assert a.complete
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.radii, b.radii)
    assert not np.array_equal(a.radii, c.radii)
    # every drawn sphere placed: the radii are the distribution's sample
    assert stats.kstest(a.radii, _truncated_cdf(stats.norm(1.0, 0.15).cdf, 0.55, 1.45)).pvalue > P_MIN


def test_random_pack_reports_what_found_no_room():
    region = R.Box([0, 0, 0], [6, 6, 6])      # room for ~ 0.38 * 216 / 4.19 = 20 unit spheres
    cloud = random_pack(region, 1.0, n=60, seed=1, attempts=200)
    assert cloud.missing > 0 and cloud.n + cloud.missing == 60 == cloud.requested
    assert _brute_force_min_gap(cloud.positions, cloud.radii) >= -1e-12


def test_overlaps_lists_each_overlapping_pair_once():
    rng = np.random.default_rng(2)
    xa, ra = rng.random((50, 3)) * 5, rng.uniform(0.1, 0.4, 50)
    xb, rb = rng.random((80, 3)) * 5, rng.uniform(0.1, 0.4, 80)
    i, j, depth = overlaps(xa, ra, xb, rb)
    d = np.sqrt(np.sum((xa[:, None] - xb[None]) ** 2, axis=2))
    ii, jj = np.nonzero(ra[:, None] + rb[None] - d > 0)
    assert sorted(zip(i.tolist(), j.tolist())) == sorted(zip(ii.tolist(), jj.tolist()))
    assert np.allclose(depth, (ra[:, None] + rb[None] - d)[i, j], rtol=0, atol=1e-14)


def test_random_pack_bad_input():
    with pytest.raises(ValueError, match="either n"):
        random_pack(R.Box([0, 0, 0], [1, 1, 1]), 0.1)
    with pytest.raises(ValueError, match="volume_fraction"):
        random_pack(R.Box([0, 0, 0], [1, 1, 1]), 0.1, volume_fraction=1.5)
    with pytest.raises(ValueError, match="expected a pardem region"):
        random_pack("box", 0.1, n=1)
    with pytest.raises(ValueError, match="expected a size distribution"):
        random_pack(R.Box([0, 0, 0], [1, 1, 1]), "big", n=1)
