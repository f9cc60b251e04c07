"""FIRE (fast inertial relaxation engine, Bitzek et al. 2006) kernels: quench a packing to rest.

Pure array kernels over the owned rows; the global sums are the caller's (``pardem.engine.relaxation``).
One FIRE update after a velocity-Verlet step, with the global ``P = F . v``, ``|F|`` and ``|v|``
(translation only: used on frictionless packings, whose torques vanish):

* ``P > 0`` (moving downhill): ``v <- (1 - a) v + a |v| F / |F|``, steering the motion along the force;
* ``P <= 0`` (uphill): ``v <- 0`` (and ``w <- 0``), the mixing ``a`` restarts; FIRE 2.0 (Guenole et
  al. 2020) first steps half a step back (``back_off``).

In the 2D mode (``pardem.engine.plane``) ``v_z = F_z = 0`` after the plane constraint, so the
mixing keeps the motion in the plane.

Used by ``pardem.engine.relaxation`` (the time loop's FIRE) and ``pardem.domains.compact`` (the
packing generator's minimiser).
"""
from numba import njit


@njit(cache=True, error_model="numpy")
def power_sums(v, f, n_owned):
    """``(F . v, |v|^2, |F|^2)`` over the owned rows (SI)."""
    p = vv = ff = 0.0
    for k in range(n_owned):
        for d in range(3):
            p += f[k, d] * v[k, d]
            vv += v[k, d] * v[k, d]
            ff += f[k, d] * f[k, d]
    return p, vv, ff


@njit(cache=True, error_model="numpy")
def mix(v, f, a, scale, n_owned):
    """``v <- (1 - a) v + a scale F`` on the owned rows (``scale = |v| / |F|``, global norms)."""
    b = 1.0 - a
    c = a * scale
    for k in range(n_owned):
        for d in range(3):
            v[k, d] = b * v[k, d] + c * f[k, d]


@njit(cache=True, error_model="numpy")
def stop(v, w, n_owned):
    """Zero the owned rows' velocities and spins."""
    for k in range(n_owned):
        for d in range(3):
            v[k, d] = 0.0
            w[k, d] = 0.0


@njit(cache=True, error_model="numpy")
def back_off(x, v, h, n_owned):
    """FIRE 2.0 back-off on the owned rows: ``x <- x - h v`` [m] (``h`` [s], half the step), then
    ``v <- 0``. Returns the largest ``|v|^2`` [m^2/s^2] before the stop (the travel bound)."""
    vmax2 = 0.0
    for k in range(n_owned):
        vk2 = 0.0
        for d in range(3):
            x[k, d] -= h * v[k, d]
            vk2 += v[k, d] * v[k, d]
            v[k, d] = 0.0
        if vk2 > vmax2:
            vmax2 = vk2
    return vmax2
