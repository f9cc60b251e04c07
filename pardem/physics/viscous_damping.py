"""Global viscous damping of the elements' motion. docs/physics.md section 8 ("damping options").

Every owned element feels ``f = -C m v`` and ``t = -C I w``: a drag proportional to its own
(absolute) velocity, used to bring a sample to rest during preparation. It is not frame
indifferent and it damps rigid-body motion too, so it has no place in a measurement run.

Free motion under it decays as ``exp(-C t)`` [C in 1/s]. With velocity Verlet the force is evaluated
with the half-step velocity, so one step multiplies the velocity by ``1 - C dt`` exactly (a relative
error ``(C dt)^2 / 2`` per step against ``exp(-C dt)``); keep ``C dt`` well below 1 (stable for
``C dt < 2``).

Only owned rows ``[0, n_owned)`` are damped: ghost rows are copies, and damping them too would count
the drag twice once ghost forces are sent back to their owners.

In the 2D mode (``pardem.engine.plane``) the drag acts on the constrained fields as they are: with
``v_z = w_x = w_y = 0`` it adds no out-of-plane force or torque, and the plane constraint runs after it.
"""
from numba import njit


@njit(cache=True, error_model="numpy")
def viscous_damping(v, w, mass, inertia, f, t, c, n_owned):
    """Add ``-c m v`` to ``f`` and ``-c I w`` to ``t`` for the owned rows.

    c : damping rate C [1/s] (>= 0). Returns the power dissipated ``sum c (m |v|^2 + I |w|^2)`` [W].
    """
    power = 0.0
    for k in range(n_owned):
        cm = c * mass[k]
        ci = c * inertia[k]
        for d in range(3):
            f[k, d] -= cm * v[k, d]
            t[k, d] -= ci * w[k, d]
        power += cm * (v[k, 0] ** 2 + v[k, 1] ** 2 + v[k, 2] ** 2)
        power += ci * (w[k, 0] ** 2 + w[k, 1] ** 2 + w[k, 2] ** 2)
    return power


def damp_elements(elements, c):
    """``viscous_damping`` on an ``Elements`` (owned rows); returns the dissipated power [W]."""
    if not c >= 0.0:
        raise ValueError(f"viscous damping rate must be >= 0 [1/s], got {c}")
    e = elements
    return viscous_damping(e.v, e.w, e.mass, e.inertia, e.f, e.t, float(c), e.n_owned)
