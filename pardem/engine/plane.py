"""The 2D mode: spheres whose centres stay in the plane z = 0 (LAMMPS' ``fix enforce2d``).

``[domain] dimension = 2`` of the granular decks (``System(dimension=2)``, ``pardem.engine.system``):
full spheres (mass ``4/3 pi rho R^3``, inertia ``2/5 m R^2``) with 3D contact laws, translating
in x, y and rotating about z only. The integrator and the contact kernels are the 3D ones; the
constraint is a fix (``PlaneConstraint``, stage ``CONSTRAINT`` of ``pardem.engine.fixes``) that
zeroes ``f_z``, ``t_x``, ``t_y`` and ``v_z``, ``w_x``, ``w_y`` of the owned rows after every force
evaluation. With velocity Verlet (``pardem.physics.verlet``) the next half kicks then leave
``v_z = w_x = w_y = 0``, so ``x_z`` stays bitwise at the plane and the orientation turns about z
only; the fix also puts ``x_z`` back on the plane (a no-op while the plane holds). Viscous damping
and FIRE act on the constrained fields (their z terms are zero). For a planar configuration
(centres at z = 0, no out-of-plane velocity, spin or load) the contact forces lie in the plane and
the torques along z on their own, so a 2D run is the 3D run of the same configuration (bit for bit,
``tests/test_two_d.py``); the fix removes what round-off or an external load would add.

The cell of a 2D case (``pardem.engine.periodic_cell.PeriodicCell(dimension=2)``) is periodic
along x and y (or not), never along z; its z edge is the thickness ``t`` of the stress convention
(default the mean diameter), so ``volume = L_x L_y t`` and the Love-Weber stress
``sum d f / V`` is the stress per unit area of the plane divided by ``t``, in Pa.
"""
import numpy as np

from pardem.engine.fixes import CONSTRAINT
from pardem.physics.verlet import enforce_plane

DIMENSIONS = (2, 3)


def check_dimension(dimension, name="dimension"):
    """``dimension`` as an int 2 or 3, or ValueError naming ``name``."""
    if isinstance(dimension, bool) or dimension not in DIMENSIONS or int(dimension) != dimension:
        raise ValueError(f"{name} = {dimension!r}: expected 2 (disks in the plane z = 0) or 3")
    return int(dimension)


class PlaneConstraint:
    """Keeps the owned elements in the plane ``z = z0`` [m], moving in x, y and turning about z.

    ``post_force(sim)``: zeroes ``f_z, t_x, t_y, v_z, w_x, w_y`` and sets ``x_z = z0`` on the owned
    rows (one Numba pass, ``physics.verlet.enforce_plane``). ``self.removed`` [3]: this rank's sum
    of the removed ``f_z`` [N], ``t_x``, ``t_y`` [N m] at the last call (zero for a planar
    configuration); ``self.off_plane`` [m]: the largest ``|x_z - z0|`` found (0 while the plane holds).
    """
    stage = CONSTRAINT
    dimension = 2

    def __init__(self, z0=0.0):
        self.z0 = float(z0)
        if not np.isfinite(self.z0):
            raise ValueError(f"z0 must be a finite plane height [m], got {z0!r}")
        self.removed = np.zeros(3)
        self.off_plane = 0.0

    def post_force(self, sim):
        e = sim.elements
        self.off_plane = float(enforce_plane(e.x, e.v, e.w, e.f, e.t, self.z0, e.n_owned, self.removed))


def plane_of(sim):
    """The ``PlaneConstraint`` among ``sim.fixes``, or None (a 3D run)."""
    return next((f for f in sim.fixes if isinstance(f, PlaneConstraint)), None)


def dimension_of(sim):
    """2 for a run in the 2D mode (its cell says so, or it holds a ``PlaneConstraint``), else 3."""
    cell = getattr(sim, "cell", None)
    if cell is not None and getattr(cell, "dimension", 3) == 2:
        return 2
    return 2 if plane_of(sim) is not None else 3


def planar(positions, name="positions"):
    """Centres [n, 3] in the plane z = 0 from [n, 2] or [n, 3] (z must be 0), or ValueError."""
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise ValueError(f"{name} must have shape (n, 2) or (n, 3) in 2D, got {x.shape}")
    if x.shape[1] == 2:
        x = np.concatenate([x, np.zeros((len(x), 1))], axis=1)
    elif np.any(x[:, 2] != 0.0):
        raise ValueError(f"{name}: in 2D the centres lie in the plane z = 0, got |z| up to "
                         f"{float(np.max(np.abs(x[:, 2]))):.3g} m")
    return np.ascontiguousarray(x)


def in_plane(vectors, components, name):
    """A copy of ``vectors`` [n, 3] with the components ``components`` (e.g. ``(2,)`` for a
    velocity, ``(0, 1)`` for a spin) zeroed: the part the plane constraint keeps."""
    if vectors is None:
        return None
    v = np.array(vectors, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {v.shape}")
    v[:, list(components)] = 0.0
    return v


__all__ = ["PlaneConstraint", "check_dimension", "plane_of", "dimension_of", "planar", "in_plane"]
