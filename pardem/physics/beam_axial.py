"""Elastic axial force of beam bonds, as ``pardem.physics.beam.beam_bond`` computes it
(docs/physics.md sections 2 and 7), for outputs that report bond forces outside the time step.

Axial force (tension positive) ``F = ka (dL + L0 p)`` [N] with ``ka = E S / L0`` [N/m], the chord
length ``L = |x_j - x_i|`` [m], ``dL = L - L0`` and the plastic strain ``p`` of a densifying bond
(its rest length is ``L0 (1 - p)``; ``p = 0`` otherwise). Damping and the yield update of the step
are not included: this is the elastic force of the current state.
"""
import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _elastic_axial_force(bi, bj, x, L0, ka, plastic, out):
    for b in range(bi.shape[0]):
        i = bi[b]
        j = bj[b]
        # the grouping of beam_bond: the same bits as the force of the step (undamped)
        dx0 = x[j, 0] - x[i, 0]
        dx1 = x[j, 1] - x[i, 1]
        dx2 = x[j, 2] - x[i, 2]
        dL = np.sqrt(dx0 * dx0 + dx1 * dx1 + dx2 * dx2) - L0[b]
        out[b] = ka[b] * (dL + L0[b] * plastic[b])


def elastic_axial_force(bi, bj, x, L0, ka, plastic):
    """Axial force [N] [n_bonds] of the bonds joining rows ``bi``, ``bj`` [n_bonds] at positions
    ``x`` [n, 3] [m]: rest length ``L0`` [m], axial stiffness ``ka`` [N/m] and plastic strain
    ``plastic`` [-], each [n_bonds]."""
    out = np.empty(len(bi))
    _elastic_axial_force(np.ascontiguousarray(bi, dtype=np.int64),
                         np.ascontiguousarray(bj, dtype=np.int64), x,
                         np.ascontiguousarray(L0, dtype=np.float64),
                         np.ascontiguousarray(ka, dtype=np.float64),
                         np.ascontiguousarray(plastic, dtype=np.float64), out)
    return out
