"""Rigid frictionless plates normal to a coordinate axis. PHYSICS.md section 5.

A plate is a plane ``x[axis] = position`` whose normal ``side`` (+1 or -1) points into the domain.
Element-plate force: linear elastic repulsion ``k * overlap`` along the normal, overlap =
``R - side * (x[axis] - position)`` when positive; no friction, no adhesion.
"""
import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def plate_forces(x, radius, f, n_owned, axis, positions, sides, stiffness, plate_force):
    """Add plate repulsion to the owned elements' ``f``.

    positions, sides, stiffness : [n_plates] plane position [m], inward normal sign, k [N/m].
    plate_force : [n_plates] output, the force the owned elements exert on each plate along its
        inward normal [N] (positive = compression of the domain against the plate).
    Returns the elastic energy stored in the element-plate contacts [J].
    """
    energy = 0.0
    for p in range(positions.shape[0]):
        plate_force[p] = 0.0
    for k in range(n_owned):
        xa = x[k, axis]
        r = radius[k]
        for p in range(positions.shape[0]):
            overlap = r - sides[p] * (xa - positions[p])
            if overlap > 0.0:
                fn = stiffness[p] * overlap
                f[k, axis] += sides[p] * fn
                plate_force[p] += fn
                energy += 0.5 * fn * overlap
    return energy
