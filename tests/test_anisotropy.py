"""Anisotropy laws (pardem.physics.anisotropy), docs/physics.md section 3.

Every law returns exactly E_L, E_R, E_T along the L, R, T axes (untilted and tilted frames); the laws
depend on the direction only through |u.L|, |u.R|, |u.T| (u and -u, mirror images through the
material planes give the same value); Hankinson's law matches its closed form at 45 degrees in each
material plane; TOR picks the nearest axis (brute-force distance to +-axes); all four laws agree with an
independent transcription of the docs/physics.md formulas at random directions, with unequal and
equal triples; a scalar and an equal triple give bitwise the same values under every law.
"""
import numpy as np
import pytest

from pardem.physics.anisotropy import INTERPOLATING, LAWS, direction_angles, evaluate, lrt_frame

VALS = (1.1e10, 7.0e8, 4.0e8)     # E_L, E_R, E_T (beech-like ratios)
TILTS = [0.0, 30.0, -45.0, 17.3, 90.0]


def random_dirs(rng, n):
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1)[:, None]


@pytest.mark.parametrize("tilt", TILTS)
@pytest.mark.parametrize("law", sorted(LAWS))
def test_axis_values_exact(law, tilt):
    frame = lrt_frame(tilt)
    for sign in (1.0, -1.0):
        got = evaluate(law, sign * frame, frame, VALS)
        np.testing.assert_allclose(got, VALS, rtol=1e-14, atol=0)


@pytest.mark.parametrize("tilt", TILTS)
def test_frame_is_a_rotation_about_T(tilt):
    F = lrt_frame(tilt)
    np.testing.assert_allclose(F @ F.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(F) == pytest.approx(1.0)
    np.testing.assert_array_equal(F[2], [0.0, 0.0, 1.0])
    a = np.radians(tilt)
    np.testing.assert_allclose(F[0], [np.cos(a), np.sin(a), 0.0], atol=1e-15)


@pytest.mark.parametrize("tilt", [0.0, 30.0])
@pytest.mark.parametrize("law", sorted(LAWS))
def test_direction_symmetries(law, tilt):
    rng = np.random.default_rng(4)
    frame = lrt_frame(tilt)
    u = random_dirs(rng, 200)
    ref = evaluate(law, u, frame, VALS)
    np.testing.assert_allclose(evaluate(law, -u, frame, VALS), ref, rtol=1e-13)
    for N in frame:   # mirror through the material plane normal to N
        m = u - 2.0 * (u @ N)[:, None] * N
        np.testing.assert_allclose(evaluate(law, m, frame, VALS), ref, rtol=1e-12)
    # the law is attached to the material: rotating u and the frame together changes nothing
    Q = lrt_frame(23.0).T @ np.array([[1, 0, 0], [0, np.cos(0.7), -np.sin(0.7)], [0, np.sin(0.7), np.cos(0.7)]])
    np.testing.assert_allclose(evaluate(law, u @ Q.T, frame @ Q.T, VALS), ref, rtol=1e-12)


@pytest.mark.parametrize("tilt", [0.0, 30.0])
def test_hankinson_closed_form(tilt):
    EL, ER, ET = VALS
    F = lrt_frame(tilt)
    L, R, T = F
    s = np.sqrt(0.5)
    u = np.array([L, s * (L + R), s * (L + T), s * (R + T)])
    got = evaluate("hankinson", u, F, VALS)
    # E(theta) = E_L E_p / (E_L sin^2 + E_p cos^2) at 45 deg: 2 E_L E_p / (E_L + E_p)
    expected = [EL, 2 * EL * ER / (EL + ER), 2 * EL * ET / (EL + ET), 2 * ER * ET / (ER + ET)]
    np.testing.assert_allclose(got, expected, rtol=1e-13)


def test_tor_picks_nearest_axis():
    rng = np.random.default_rng(9)
    for tilt in (0.0, 30.0):
        F = lrt_frame(tilt)
        u = random_dirs(rng, 2000)
        # brute force: distance to the six unit vectors +-L, +-R, +-T
        d = np.stack([np.minimum(np.linalg.norm(u - a, axis=1), np.linalg.norm(u + a, axis=1))
                      for a in F], axis=1)
        expected = np.asarray(VALS)[np.argmin(d, axis=1)]
        np.testing.assert_array_equal(evaluate("TOR", u, F, VALS), expected)


def _spec(law, u, frame, vL, vR, vT):
    """docs/physics.md section 3 transcribed independently (theta from atan2, phi in the RT plane)."""
    c = np.abs(u @ frame.T)
    theta = np.arctan2(np.hypot(c[:, 1], c[:, 2]), c[:, 0])
    phi = np.arctan2(c[:, 2], c[:, 1])
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
    h = np.pi / 2
    if law == "hankinson":
        Ep = vR * vT / (vR * sp**2 + vT * cp**2)
        return vL * Ep / (vL * st**2 + Ep * ct**2)
    if law == "linear":
        return vL + (vR - vL) * theta / h + (vT - vR) * theta * phi / h**2
    if law == "spherical":
        return ct * vL + st * cp * vR + st * sp * vT
    if law == "spherical_normalised":
        return (ct * vL + st * cp * vR + st * sp * vT) / (ct + st * cp + st * sp)
    raise ValueError(law)


@pytest.mark.parametrize("law", ["hankinson", "linear", "spherical", "spherical_normalised"])
def test_laws_match_formulas(law):
    rng = np.random.default_rng(12)
    F = lrt_frame(30.0)
    u = random_dirs(rng, 500)
    np.testing.assert_allclose(evaluate(law, u, F, VALS), _spec(law, u, F, *VALS), rtol=1e-10)


@pytest.mark.parametrize("law", sorted(LAWS))
def test_law_formulas_with_equal_triple(law):
    """Each law's own formula (``LAWS[law]``, no shortcut) on (v, v, v) against an independent value:
    v for the interpolating laws, v (cL + cR + cT) = v (|u.L| + |u.R| + |u.T|) for W's spherical law
    (1.41 v at 45 deg in a material plane, 1.73 v on the diagonal). Tolerance 1e-13: rounding of
    the trigonometric forms."""
    rng = np.random.default_rng(21)
    F = lrt_frame(30.0)
    L, R, T = F
    u = np.vstack([random_dirs(rng, 300), np.sqrt(0.5) * (L + R), (L + R + T) / np.sqrt(3.0)])
    v = 3.3e8
    c, theta, phi = direction_angles(u, F)
    got = LAWS[law](c, theta, phi, v, v, v)
    if law == "spherical":
        expected = v * np.abs(u @ F.T).sum(axis=1)
        assert got[-2] == pytest.approx(np.sqrt(2.0) * v, rel=1e-13)
        assert got[-1] == pytest.approx(np.sqrt(3.0) * v, rel=1e-13)
    else:
        assert law in INTERPOLATING
        expected = np.full(len(u), v)
    if law == "TOR":
        np.testing.assert_array_equal(got, expected)
    else:
        np.testing.assert_allclose(got, expected, rtol=1e-13)
    if law == "spherical_normalised":   # unequal: a weighted mean, inside [min, max]
        w = np.abs(u @ F.T)
        got_u = LAWS[law](c, theta, phi, *VALS)
        np.testing.assert_allclose(got_u, (w @ np.asarray(VALS)) / w.sum(axis=1), rtol=1e-13)


@pytest.mark.parametrize("law", sorted(LAWS))
def test_scalar_and_equal_triple_are_the_same_for_every_law(law):
    """The issue's consistency: ``young = v`` and ``[v, v, v]`` give bitwise the same values, and the
    value of W's spherical law for either is its formula's (not a shortcut to v)."""
    u = random_dirs(np.random.default_rng(4), 200)
    F = lrt_frame(17.0)
    scalar, triple = evaluate(law, u, F, 0.7), evaluate(law, u, F, [0.7, 0.7, 0.7])
    np.testing.assert_array_equal(scalar, triple)
    if law == "spherical":
        np.testing.assert_allclose(scalar, 0.7 * np.abs(u @ F.T).sum(axis=1), rtol=1e-13)
        assert scalar.max() > 1.5 * 0.7          # random directions reach near the diagonal's sqrt(3)
    else:
        np.testing.assert_array_equal(scalar, np.full(200, 0.7))


def test_unknown_law_is_refused():
    with pytest.raises(ValueError, match="expected one of"):
        evaluate("elliptic", np.eye(3), np.eye(3), VALS)


@pytest.mark.parametrize("law", ["TOR", "hankinson", "linear", "spherical_normalised"])
def test_bounded_and_isotropic(law):
    """These laws interpolate: values stay within [min, max], and so an isotropic input stays
    isotropic, through the law's own formula (``LAWS[law]``: ``evaluate`` returns an equal triple's
    value without it). Tolerance 1e-14: a few roundings of 1.1e-16 in each formula."""
    rng = np.random.default_rng(13)
    F = lrt_frame(30.0)
    u = random_dirs(rng, 500)
    c, theta, phi = direction_angles(u, F)
    for vals in (VALS, (5.0e8, 5.0e8, 5.0e8)):
        v = LAWS[law](c, theta, phi, *vals)
        assert np.all(v >= min(vals) * (1 - 1e-14)) and np.all(v <= max(vals) * (1 + 1e-14)), vals
    np.testing.assert_array_equal(evaluate(law, u, F, VALS), LAWS[law](c, theta, phi, *VALS))
