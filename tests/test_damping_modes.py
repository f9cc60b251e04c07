"""Damping ratio of every mode of a two-element beam bond (docs/physics.md section 2).

A free bonded pair has six deformation modes: axial, twist, two bending modes (the ends turning
opposite ways, no shear force) and two transverse (shear) modes (the ends turning the same way
while the centres move across the bond, carrying the shear force). Each must have the damping
ratio ``zeta`` of the bond material. Two independent measurements:

* **Linearised modal analysis**: the stiffness ``K`` (central differences of the kernel's loads
  in the 12 positions and rotation vectors) and the damping matrix ``C`` (the loads at unit
  velocities: the damping is linear in the rates) of the pair, with its mass matrix ``M``, give the
  eigenvalues ``lambda`` of ``M x'' + C x' + K x = 0``; each mode's ratio is ``-Re lambda /
  |lambda|`` and its frequency ``|lambda|``. The frequencies are checked against the closed forms
  of the free pair (below), which identifies the modes.
* **Free decay** of each mode of an identical pair in the time loop (velocity Verlet): the
  logarithmic decrement of the released mode.

Closed forms for identical spheres (mass m, inertia I, m* = m/2, I* = I/2, bond length L0):
axial ``ka / m*``; twist ``kt / I*``; bending ``kb / (L0 I*)``; transverse: with both ends turned by
``th`` relative to the chord and zero angular momentum, the mode's stiffness is ``12 kb / L0`` on
``th`` and its inertia ``(2I) m* L0^2 / (2I + m* L0^2)`` (the end inertias in series with the
pair's rotary inertia), so ``omega_s^2 = 12 kb / L0 (1 / (2 I) + 1 / (m* L0^2))``.
"""
import numpy as np
import pytest

from _util import (free_oscillation, loads, log_decrement_ratio, reduced, relative_rotation, rotate_element,
                   two_elements)

YOUNG, RR, NU = 2.0e9, 0.6, 0.3


def _state_copy(e):
    return e.x.copy(), e.q.copy(), e.v.copy(), e.w.copy()


def _restore(e, st):
    e.x[:], e.q[:], e.v[:], e.w[:] = (a.copy() for a in st)
    e.refresh_rotations()


def _generalised_loads(b, e):
    f, t, _ = loads(b, e)
    return np.concatenate([f[0], t[0], f[1], t[1]])


def linear_matrices(e, b, h_rel=1e-7):
    """(M, K, C) [12 x 12] of the pair at rest about its current (unloaded) state.

    Coordinates: x1, theta1, x2, theta2 (world rotation vectors). K by central differences of the
    loads (step ``h_rel`` of the bond length or 1 rad), C from the loads at unit rates (the damping
    loads are linear in v and w)."""
    ref = _state_copy(e)
    L0 = float(b.L0[0])
    M = np.diag(np.concatenate([[e.mass[0]] * 3, [e.inertia[0]] * 3,
                                [e.mass[1]] * 3, [e.inertia[1]] * 3]))
    K = np.zeros((12, 12))
    C = np.zeros((12, 12))
    for col in range(12):
        k, kind, axis = col // 6, (col % 6) // 3, col % 3
        h = h_rel * (L0 if kind == 0 else 1.0)
        q_pm = []
        for sign in (1.0, -1.0):
            _restore(e, ref)
            if kind == 0:
                e.x[k, axis] += sign * h
            else:
                rv = np.zeros(3)
                rv[axis] = sign * h
                rotate_element(e, k, rv)
            q_pm.append(_generalised_loads(b, e))
        K[:, col] = -(q_pm[0] - q_pm[1]) / (2.0 * h)
        _restore(e, ref)
        (e.v if kind == 0 else e.w)[k, axis] = 1.0
        C[:, col] = -(_generalised_loads(b, e) - _generalised_loads_at_rest(b, e, ref))
    _restore(e, ref)
    return M, K, C


def _generalised_loads_at_rest(b, e, ref):
    v, w = e.v.copy(), e.w.copy()
    e.v[:] = 0.0
    e.w[:] = 0.0
    out = _generalised_loads(b, e)
    e.v[:], e.w[:] = v, w
    return out


def modal_damping(M, K, C):
    """(omega [rad/s], zeta) of the oscillating modes, sorted by omega (each conjugate pair once;
    the six rigid-body modes, |lambda| ~ 0, are left out)."""
    n = len(M)
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]])
    lam = np.linalg.eigvals(A)
    scale = np.sqrt(np.max(np.abs(np.diag(K)) / np.diag(M)))
    lam = lam[(lam.imag > 0.0) & (np.abs(lam) > 1e-3 * scale)]
    order = np.argsort(np.abs(lam))
    lam = lam[order]
    return np.abs(lam), -lam.real / np.abs(lam)


def closed_form_frequencies(e, b):
    """The closed-form frequencies of the identical pair's modes, by name (module docstring)."""
    m, I = e.mass[0], e.inertia[0]
    m_red, i_red = m / 2.0, I / 2.0
    L0, ka, kb, kt = b.L0[0], b.ka[0], b.kb[0], b.kt[0]
    return {
        "axial": np.sqrt(ka / m_red),
        "twist": np.sqrt(kt / i_red),
        "bending": np.sqrt(kb / (L0 * i_red)),
        "transverse": np.sqrt(12.0 * kb / L0 * (1.0 / (2.0 * I) + 1.0 / (m_red * L0**2))),
    }


@pytest.mark.parametrize("zeta", [0.05, 0.2])
def test_modal_damping_ratios_of_an_identical_pair(zeta):
    """All six deformation modes of an identical pair: frequencies of the closed forms, ratio zeta."""
    R = 1.0e-3
    e, b = two_elements((0.3, -0.5, 0.8), R, R, YOUNG, RR, NU, zeta)
    M, K, C = linear_matrices(e, b)
    omega, ratio = modal_damping(M, K, C)
    assert len(omega) == 6
    expected = closed_form_frequencies(e, b)
    names = []
    for w in omega:
        # each mode is named by the closed form it matches; the four differ by > 20 % here
        name = min(expected, key=lambda k: abs(expected[k] / w - 1.0))
        # damped eigenvalue modulus |lambda| = omega_n exactly; 1e-4: finite-difference K (h = 1e-7)
        assert w == pytest.approx(expected[name], rel=1e-4), (name, w, expected[name])
        names.append(name)
    assert sorted(names) == sorted(["axial", "twist", "bending", "bending", "transverse",
                                    "transverse"])
    for name, z in zip(names, ratio):
        # Kelvin-Voigt modes: ratio = tau omega / 2 exactly; 1e-4: finite-difference K
        assert z == pytest.approx(zeta, rel=1e-4), (
            f"{name} mode damping ratio {z:.5f}, expected zeta = {zeta}")


@pytest.mark.parametrize("r2", [1.1e-3, 1.5e-3, 2.0e-3])
def test_modal_damping_ratios_of_an_unequal_pair(r2):
    """R2 != R1 (compact domains): the bending and transverse modes couple through the unequal end
    inertias, and each of the six modes must still have the ratio zeta."""
    zeta = 0.2
    e, b = two_elements((0.6, 0.0, -0.8), 1.0e-3, r2, YOUNG, RR, NU, zeta)
    M, K, C = linear_matrices(e, b)
    omega, ratio = modal_damping(M, K, C)
    assert len(omega) == 6
    exact = {"axial": np.sqrt(b.ka[0] / reduced(e.mass[0], e.mass[1])),
             "twist": np.sqrt(b.kt[0] / reduced(e.inertia[0], e.inertia[1]))}
    for name, w0 in exact.items():
        assert np.min(np.abs(omega / w0 - 1.0)) < 1e-4, name   # 1e-4: finite-difference K
    # every mode, 1e-4: finite-difference K
    np.testing.assert_allclose(ratio, zeta, rtol=1e-4)


# ----------------------------------------------------------------------------------------------
# free decay in the time loop

@pytest.mark.parametrize("mode", ["axial", "twist", "bending", "transverse"])
def test_free_decay_of_each_mode(mode):
    """An identical pair released in one mode decays at ratio zeta (log decrement) at the
    closed-form frequency (zero crossings)."""
    zeta = 0.2
    R = 1.0e-3
    e, b = two_elements((1.0, 0.0, 0.0), R, R, YOUNG, RR, NU, zeta)
    omega = closed_form_frequencies(e, b)[mode]
    L0 = 2.0 * R
    X, Y, Z = np.eye(3)
    A = 1e-5
    if mode == "axial":
        e.x[1] += A * L0 * X
        measure = lambda el: el.x[1, 0] - el.x[0, 0] - L0
    elif mode == "twist":
        rotate_element(e, 1, A * X)
        measure = lambda el: relative_rotation(el, X)
    elif mode == "bending":
        rotate_element(e, 0, -0.5 * A * Z)
        rotate_element(e, 1, 0.5 * A * Z)
        measure = lambda el: relative_rotation(el, Z)
    else:
        # chord turned by psi (centres moved across), both ends turned by phi = -beta psi, so that
        # the angular momentum is zero: beta = m* L0^2 / (2 I)
        beta = 0.5 * e.mass[0] * L0**2 / (2.0 * e.inertia[0])
        psi = A
        e.x[0, 1] -= 0.5 * psi * L0
        e.x[1, 1] += 0.5 * psi * L0
        rotate_element(e, 0, -beta * psi * Z)
        rotate_element(e, 1, -beta * psi * Z)
        measure = lambda el: el.x[1, 1] - el.x[0, 1]
    e.x0[:] = e.x
    s, dt = free_oscillation(e, b, omega * np.sqrt(1.0 - zeta**2), measure)
    s = s / np.abs(s[0])
    crossings = np.nonzero(np.sign(s[1:]) != np.sign(s[:-1]))[0]
    half_period = np.mean(np.diff(crossings)) * dt
    # damped half period pi / omega_d; 1 %: crossings resolved to 1/400 of a period, linear interp.
    # not used (0.25 % per crossing), and the finite amplitude 1e-5 is linear to 1e-5
    assert half_period == pytest.approx(np.pi / (omega * np.sqrt(1 - zeta**2)), rel=0.01)
    measured = log_decrement_ratio(s)
    # 3 %: Verlet's damping error at 400 steps per period (omega dt = 0.016: relative O(omega dt)
    # on the decrement) and the parabolic peak estimate
    assert measured == pytest.approx(zeta, rel=0.03), (
        f"{mode} mode damping ratio {measured:.4f}, expected zeta = {zeta}")
