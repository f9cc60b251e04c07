"""A periodic cell that may deform at a homogeneous diagonal strain rate, with a pressure servo.

PHYSICS.md sections 11 and 12. The cell is the box ``[lo, lo + L)`` along its periodic axes. When it
deforms at the diagonal rate ``g`` [1/s] (engineering rate of the edge lengths, positive in
extension), every step maps the owned positions affinely, ``x <- lo + (x - lo)(1 + g dt)``, and the
edges ``L <- L (1 + g dt)``. Velocities stay the fluctuations about that affine field (so the
kinetic energy is the granular temperature's), and the contact kernels add the affine relative
motion ``-g d`` of each pair (``contact_frame.affine_motion``).

Servo-control of the mean stress (PHYSICS.md section 12): ``g = gain (p - p0)`` on every axis with
``p = -trace(sigma) / 3`` the pressure (positive in compression) from the Love-Weber stress, so the
cell expands when the packing is above the target pressure and shrinks below it; ``|g|`` is capped
by ``max_rate``. Units: ``gain`` [1/(Pa s)], ``p0`` [Pa].

The cell is pure bookkeeping over arrays; the reductions it needs (the global stress) are done by
the caller.
"""
import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _affine_map(x, n, lo, factor):
    for k in range(n):
        for d in range(3):
            if factor[d] != 1.0:
                x[k, d] = lo[d] + (x[k, d] - lo[d]) * factor[d]


@njit(cache=True, error_model="numpy")
def _wrap(x, n, lo, length, periodic):
    for k in range(n):
        for d in range(3):
            if periodic[d]:
                m = np.floor((x[k, d] - lo[d]) / length[d])
                if m != 0.0:
                    x[k, d] -= m * length[d]


class PeriodicCell:
    """Box ``lo`` [3] [m] with edges ``length`` [3] [m]; ``periodic`` [3] bools.

    ``rate`` [3] [1/s]: imposed diagonal strain rate (along periodic axes only); ``servo``: None or
    ``(p0 [Pa], gain [1/(Pa s)], max_rate [1/s])`` for an isotropic pressure control.
    """

    def __init__(self, lo, length, periodic, rate=(0.0, 0.0, 0.0), servo=None):
        self.lo = np.asarray(lo, dtype=np.float64).copy()
        self.length = np.asarray(length, dtype=np.float64).copy()
        self.periodic = np.array([bool(p) for p in periodic], dtype=np.bool_)
        self.rate = np.asarray(rate, dtype=np.float64).copy()
        if np.any(self.rate[~self.periodic] != 0.0):
            raise ValueError("cell.rate: a strain rate needs a periodic axis (non-periodic axes take 0)")
        if not np.all(self.length > 0.0):
            raise ValueError(f"cell.length must be positive along every axis, got {list(self.length)}")
        self.servo = None if servo is None else tuple(float(v) for v in servo)
        self.strain = np.zeros(3)   # accumulated log strain of the edges since the start
        self.strain_since_build = 0.0   # largest |strain| increment since the last list build

    @property
    def hi(self):
        return self.lo + self.length

    @property
    def volume(self):
        return float(np.prod(self.length))

    @property
    def deforming(self):
        return self.servo is not None or bool(np.any(self.rate != 0.0))

    def deform(self, elements, dt, references=()):
        """Map the owned rows and the ``references`` position arrays affinely over one step;
        returns the step's stretch factor per axis [3] (None when the cell does not deform)."""
        if not self.deforming:
            return None
        factor = 1.0 + self.rate * dt
        _affine_map(elements.x, elements.n_owned, self.lo, factor)
        for ref in references:
            if ref is not None:
                _affine_map(ref, ref.shape[0], self.lo, factor)
        self.length *= factor
        self.strain += np.log(factor)
        self.strain_since_build += float(np.max(np.abs(np.log(factor))))
        return factor

    def wrap(self, elements):
        """Bring the owned rows into ``[lo, lo + L)`` along the periodic axes (at list rebuilds)."""
        _wrap(elements.x, elements.n_owned, self.lo, self.length, self.periodic)

    def shift_metres(self, shifts):
        """Image shifts of a pair list [n, 3] int8 in metres for the current edges."""
        return shifts * np.where(self.periodic, self.length, 0.0)

    def control(self, stress):
        """Servo update of ``rate`` from the global stress tensor [3, 3] [Pa] (tension positive)."""
        if self.servo is None:
            return
        p0, gain, max_rate = self.servo
        p = -float(np.trace(stress)) / 3.0
        g = float(np.clip(gain * (p - p0), -max_rate, max_rate))
        self.rate = np.where(self.periodic, g, 0.0)

    def state(self):
        """Everything needed to restart the cell (JSON friendly)."""
        return {"lo": self.lo.tolist(), "length": self.length.tolist(),
                "periodic": self.periodic.tolist(), "rate": self.rate.tolist(),
                "servo": None if self.servo is None else list(self.servo),
                "strain": self.strain.tolist(), "strain_since_build": self.strain_since_build}

    @classmethod
    def from_state(cls, s):
        cell = cls(s["lo"], s["length"], s["periodic"], s["rate"], s["servo"])
        cell.strain = np.asarray(s["strain"], dtype=np.float64)
        cell.strain_since_build = float(s["strain_since_build"])
        return cell
