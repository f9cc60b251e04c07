"""Anisotropic bond properties from the bond direction. docs/physics.md section 3.

Orthotropy frame L, R, T (rows of ``frame``). For a unit bond direction ``u``:
``cL, cR, cT = |u.L|, |u.R|, |u.T|``, ``theta = arccos(cL)`` (from L), ``phi = atan2(cT, cR)``
(in the RT plane, from R). Each law maps ``(values_L, values_R, values_T)`` to the bond's value and
returns exactly the axis value along each axis. The laws apply to moduli, bond radii and strengths.

A scalar value is the triple ``(v, v, v)``: it goes through the law like any triple, so a scalar and an
equal triple give the same bonds under every law (bitwise). The interpolating laws (``INTERPOLATING``:
TOR, hankinson, linear, spherical_normalised) return ``v`` for an equal triple; they return it exactly
(their formulas would differ from ``v`` by rounding). W's ``spherical`` law, a sum of direction cosines,
is not an interpolation: an equal triple gives ``v (cL + cR + cT)`` (up to ``sqrt(3) v``), for a scalar
too; ``spherical_normalised`` divides it by ``cL + cR + cT`` (a weighted mean of the axis values).
"""
import numpy as np


def direction_angles(u, frame):
    """Direction cosines [n, 3] (|u.L|, |u.R|, |u.T|), theta [n] and phi [n] of unit vectors ``u``."""
    c = np.abs(np.asarray(u) @ np.asarray(frame).T)
    c = np.minimum(c, 1.0)
    theta = np.arccos(c[:, 0])
    phi = np.arctan2(c[:, 2], c[:, 1])
    return c, theta, phi


def law_tor(c, theta, phi, vL, vR, vT):
    """All or nothing: the value of the frame axis closest to the bond (ties go L, then R, then T)."""
    return np.choose(np.argmax(c, axis=1), [vL, vR, vT]).astype(np.float64)


def law_hankinson(c, theta, phi, vL, vR, vT):
    """Hankinson's formula in the RT plane, then between L and that plane."""
    vp = vR * vT / (vR * np.sin(phi) ** 2 + vT * np.cos(phi) ** 2)
    return vL * vp / (vL * np.sin(theta) ** 2 + vp * np.cos(theta) ** 2)


def law_linear(c, theta, phi, vL, vR, vT):
    """Linear in theta, then bilinear in (theta, phi)."""
    h = np.pi / 2
    return vL + (vR - vL) * theta / h + (vT - vR) * theta * phi / h**2


def law_spherical(c, theta, phi, vL, vR, vT):
    """Weighted by the direction cosines: cos(theta) vL + sin(theta)cos(phi) vR + sin(theta)sin(phi) vT."""
    return (np.cos(theta) * vL + np.sin(theta) * np.cos(phi) * vR
            + np.sin(theta) * np.sin(phi) * vT)


def law_spherical_normalised(c, theta, phi, vL, vR, vT):
    """W's spherical law divided by the sum of its weights: (cL vL + cR vR + cT vT) / (cL + cR + cT)."""
    return (c[:, 0] * vL + c[:, 1] * vR + c[:, 2] * vT) / c.sum(axis=1)


LAWS = {
    "TOR": law_tor,
    "hankinson": law_hankinson,
    "linear": law_linear,
    "spherical": law_spherical,
    "spherical_normalised": law_spherical_normalised,
}
# laws that return v in every direction for the triple (v, v, v) (module docstring)
INTERPOLATING = frozenset(("TOR", "hankinson", "linear", "spherical_normalised"))


def evaluate(law, u, frame, values):
    """Value of an anisotropic property for bond directions ``u`` [n, 3] by ``law`` (a key of LAWS).

    values : (v_L, v_R, v_T), or a scalar v = (v, v, v): the same bonds under every law (module
        docstring: the spherical law scales it by cL + cR + cT).
    """
    vals = np.broadcast_to(np.asarray(values, dtype=np.float64), (3,))
    if law not in LAWS:
        raise ValueError(f"anisotropy law {law!r}: expected one of {', '.join(LAWS)}")
    if law in INTERPOLATING and vals[0] == vals[1] == vals[2]:
        return np.full(len(u), float(vals[0]))
    c, theta, phi = direction_angles(u, frame)
    return LAWS[law](c, theta, phi, vals[0], vals[1], vals[2])


def lrt_frame(tilt_deg):
    """Rows L, R, T of the material frame tilted by ``tilt_deg`` about T (= z) in the LR plane."""
    a = np.radians(tilt_deg)
    return np.array([[np.cos(a), np.sin(a), 0.0],
                     [-np.sin(a), np.cos(a), 0.0],
                     [0.0, 0.0, 1.0]])
