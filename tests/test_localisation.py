"""Local strain (least-squares displacement gradient) and shear-band detection, against fields
whose answer is known: affine displacements, rigid rotations, and a synthetic band."""
import numpy as np
import pytest

from pardem.physics import local_strain, shear_band, structure


def packing(n=400, dim=2, seed=3):
    rng = np.random.default_rng(seed)
    L = 1e-2
    x = np.zeros((n, 3))
    x[:, :dim] = rng.uniform(0.0, L, size=(n, dim))
    cut = 2.2 * L / n ** (1 / dim)
    i, j, branch = structure.neighbour_pairs(x, cut, dim=dim)
    return x, i, j, branch


@pytest.mark.parametrize("dim", [2, 3])
def test_an_affine_field_is_recovered_at_every_grain(dim):
    x, i, j, branch = packing(dim=dim, n=400 if dim == 2 else 800)
    rng = np.random.default_rng(1)
    G0 = rng.normal(scale=1e-3, size=(dim, dim))
    u = np.zeros_like(x)
    u[:, :dim] = x[:, :dim] @ G0.T + 1e-4             # u = G0 x + c
    du = u[j] - u[i]
    G = local_strain.displacement_gradient(len(x), i, j, branch, du, dim=dim)
    ok = np.all(np.isfinite(G), axis=(1, 2))
    assert ok.mean() > 0.95                           # almost every grain has spanning neighbours
    # exact to round-off: |G0| 1e-3, the normal equations' condition ~1e2 -> 1e-14 absolute
    assert np.max(np.abs(G[ok] - G0)) < 1e-13
    m = local_strain.strain_measures(G[ok])
    assert np.allclose(m["strain"], 0.5 * (G0 + G0.T), atol=1e-13)
    assert np.allclose(m["volumetric"], np.trace(G0), atol=1e-13)


def test_a_rigid_rotation_has_no_strain_and_its_angle():
    x, i, j, branch = packing()
    theta = 2e-3
    R = np.array([[0.0, -theta], [theta, 0.0]])        # small rotation: u = (R - I) x to first order
    u = np.zeros_like(x)
    u[:, :2] = x[:, :2] @ R.T
    G = local_strain.displacement_gradient(len(x), i, j, branch, u[j] - u[i], dim=2)
    m = local_strain.strain_measures(G)
    ok = np.isfinite(m["shear"])
    assert np.max(m["shear"][ok]) < 1e-14 and np.allclose(m["rotation"][ok], theta, rtol=1e-10)


def test_a_grain_without_spanning_neighbours_gets_nan():
    x = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float)   # collinear
    i, j = np.array([0, 1]), np.array([1, 2])
    G = local_strain.displacement_gradient(3, i, j, x[j] - x[i], np.zeros((2, 3)), dim=2)
    assert np.all(np.isnan(G))


def test_a_synthetic_band_is_found_with_its_angle_position_and_width():
    """Shear = g0 exp(-s^2 / 2 w^2) + noise across a line at 125 deg from x (folded: 55 deg)
    through (40, 90) d: the fit gives the angle within 1 deg (the band is 10 times longer than
    wide), the centre on the line within 1 d, the FWHM 2.355 w within 10 % (1 d bins smear it by
    sqrt(w^2 + 1/12))."""
    rng = np.random.default_rng(8)
    d = 2e-4
    x = rng.uniform([0, 0], [80 * d, 180 * d], size=(6000, 2))
    a = np.radians(125.0)
    direction = np.array([np.cos(a), np.sin(a)])
    normal = np.array([-direction[1], direction[0]])
    c0 = np.array([40 * d, 90 * d])
    s = (x - c0) @ normal / d
    w = 2.5
    g = 0.05 * np.exp(-s ** 2 / (2 * w ** 2)) + rng.uniform(0, 0.002, size=len(x))
    band = shear_band.detect(x, g, d)
    assert band["angle_deg"] == pytest.approx(55.0, abs=1.0)
    assert abs((np.array(band["centre"]) - c0) @ normal) < d
    assert band["width_d"] == pytest.approx(2.3548 * w, rel=0.10)


def test_the_classical_band_angles():
    p = shear_band.predictions(30.0, 10.0)
    assert p == {"mohr_coulomb": 60.0, "roscoe": 50.0, "arthur": 55.0}
