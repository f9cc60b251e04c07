"""A periodic cell that may deform at a homogeneous diagonal strain rate, with a pressure servo.

docs/physics.md sections 11 and 12. The cell is the box ``[lo, lo + L)`` along its periodic axes. When it
deforms at the diagonal rate ``g`` [1/s] (engineering rate of the edge lengths, positive in
extension), every step maps the owned positions affinely, ``x <- lo + (x - lo)(1 + g dt)``, and the
edges ``L <- L (1 + g dt)``. Velocities stay the fluctuations about that affine field (so the
kinetic energy is the granular temperature's), and the contact kernels add the affine relative
motion ``-g d`` of each pair (``contact_frame.affine_motion``).

Servo-control of the mean stress (docs/physics.md section 12): ``g = gain (p - p0)`` on every axis with
``p = -trace(sigma) / 3`` the pressure (positive in compression) from the Love-Weber stress, so the
cell expands when the packing is above the target pressure and shrinks below it; ``|g|`` is capped
by ``max_rate``. Units: ``gain`` [1/(Pa s)], ``p0`` [Pa]. The loop is discrete: one step changes
the pressure by ``-S g dt``, with ``S = -dp/de`` [Pa] the packing's affine stiffness, so the error is
multiplied by ``1 - S gain dt`` per step and the loop diverges once ``S gain dt > 2``. A
stiff packing at low pressure (Hertz: ``S / p`` grows as ``p^(-2/3)``) or a long step gets there.
When the caller sets ``servo_stiffness = S`` (``Contacts.stiffness``), ``control`` therefore uses
``min(gain, 1 / (2 S dt))``, which at most halves the error per step and does not overshoot.

Triaxial control (docs/physics.md section 12; ``triaxial_servo``): the axial axis ``a`` deforms at an
imposed rate (negative: compression), and each lateral axis ``b`` servos its own normal stress to the
confining pressure, ``g_b = gain (-sigma_bb - pc)`` capped by ``max_rate``, so the lateral stress is
held at ``sigma_bb = -pc`` (tension positive).

2D cells (``dimension = 2``, the 2D mode of ``pardem.engine.plane``): the grains lie in the plane
z = 0; the cell is never periodic along z and never deforms along it, and its z edge is the
thickness ``t`` of the 2D stress convention (the mean diameter by default), so ``volume = L_x L_y t``
and the Love-Weber stress ``sum d f / V`` is the stress per unit area of the plane over ``t`` [Pa].
The pressure of the servo is the in-plane mean stress ``p = -(s_xx + s_yy) / 2``, and the
triaxial servo becomes biaxial (axis x or y imposed, the other in-plane axis servoed).

Simple shear (docs/physics.md section 12; LAMMPS' triclinic box): the cell may also be tilted, its
edge vectors the columns of the upper-triangular ``H = [[L_x, xy, xz], [0, L_y, yz], [0, 0, L_z]]``
(``tilt = (xy, xz, yz)`` [m]), so that an image across y is shifted along x by ``xy`` (Lees-Edwards).
``shear_rate = (g_xy, g_xz, g_yz)`` [1/s] are the off-diagonal entries ``dv_x/dy``, ``dv_x/dz``,
``dv_y/dz`` of the velocity gradient ``Lv = diag(rate) + upper(shear_rate)``; every step maps
``x <- lo + (1 + Lv dt)(x - lo)`` and ``H <- (1 + Lv dt) H``, and the contact kernels add the affine
relative motion ``-Lv d`` (``contact_frame.shear_motion``). Velocities stay the fluctuations about
the affine field, so a grain wrapped across y keeps its velocity (LAMMPS' ``remap v`` adds the
streaming jump to total velocities instead). A tilt beyond half its edge is flipped by one edge
(LAMMPS ``flip``: ``yz`` by ``L_y``, which moves ``xz`` by ``xy``, then ``xz`` and ``xy`` by
``L_x``): the lattice of images is unchanged, its integer image labels are not, so a flip asks for
a neighbour-list rebuild (``strain_since_build`` infinite until the rebuild resets it). A slab
decomposition along x needs ``xy = xz = 0`` (and no x shear rate), along y ``yz = 0``
(``slab_axis_allowed``); the ghosts need no image shift of their own, since the neighbour list
finds the image of every row through ``H``.

Normal-stress servo (``normal_servo``, with simple shear): axis ``a`` servoes its normal stress to
``-pressure`` (``g_a = gain (-sigma_aa - pressure)`` capped by ``max_rate``), the other axes keep
their edges.

The cell is pure bookkeeping over arrays; the reductions it needs (the global stress) are done by
the caller.
"""
import numpy as np
from numba import njit

from pardem.physics.arguments import is_real, keywords, real, short, vector3
from pardem.physics.contact_frame import any_rate


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


@njit(cache=True, error_model="numpy")
def _shear_map(x, n, lo, factor, sxy, sxz, syz):
    """``x <- lo + (1 + Lv dt)(x - lo)`` with ``Lv dt`` upper triangular: diagonal ``factor - 1``,
    off-diagonal ``sxy, sxz, syz`` (the step's shear strains); axes that do not move are left
    untouched (no rounding)."""
    move1 = factor[1] != 1.0 or syz != 0.0
    for k in range(n):
        r1 = x[k, 1] - lo[1]
        r2 = x[k, 2] - lo[2]
        x[k, 0] = lo[0] + ((x[k, 0] - lo[0]) * factor[0] + (sxy * r1 + sxz * r2))
        if move1:
            x[k, 1] = lo[1] + (r1 * factor[1] + syz * r2)
        if factor[2] != 1.0:
            x[k, 2] = lo[2] + r2 * factor[2]


@njit(cache=True, error_model="numpy")
def _wrap_tilted(x, n, lo, length, tilt, periodic):
    """``_wrap`` in a tilted cell: the fractional coordinates ``H^-1 (x - lo)`` into [0, 1), z first
    (H is upper triangular: an image along z moves x and y too, one along y moves x)."""
    for k in range(n):
        if periodic[2]:
            m = np.floor((x[k, 2] - lo[2]) / length[2])
            if m != 0.0:
                x[k, 2] -= m * length[2]
                x[k, 1] -= m * tilt[2]
                x[k, 0] -= m * tilt[1]
        if periodic[1]:
            m = np.floor(((x[k, 1] - lo[1]) - tilt[2] * ((x[k, 2] - lo[2]) / length[2])) / length[1])
            if m != 0.0:
                x[k, 1] -= m * length[1]
                x[k, 0] -= m * tilt[0]
        if periodic[0]:
            s2 = (x[k, 2] - lo[2]) / length[2] if periodic[2] else 0.0
            s1 = ((x[k, 1] - lo[1]) - tilt[2] * s2) / length[1] if periodic[1] else 0.0
            m = np.floor(((x[k, 0] - lo[0]) - tilt[0] * s1 - tilt[1] * s2) / length[0])
            if m != 0.0:
                x[k, 0] -= m * length[0]


# which two axes each tilt (xy, xz, yz) couples: (the shifted axis, the axis crossed)
TILT_AXES = ((0, 1), (0, 2), (1, 2))


def _flags(name, value):
    """Three booleans (bools, or the integers 0 and 1) as a bool array [3], or ValueError naming
    ``name`` (``bool("no")`` would be True: strings are refused)."""
    items = list(value) if isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray)
                                                                and value.ndim == 1) else []
    if len(items) != 3 or not all(isinstance(p, (bool, np.bool_))
                                  or (is_real(p) and not isinstance(p, float) and p in (0, 1)) for p in items):
        raise ValueError(f"{name} = {short(value)}: expected 3 booleans (one per axis x, y, z)")
    return np.array([bool(p) for p in items], dtype=np.bool_)


@keywords("PeriodicCell")
class PeriodicCell:
    """Box ``lo`` [3] [m] with edges ``length`` [3] [m]; ``periodic`` [3] bools.

    ``rate`` [3] [1/s]: imposed diagonal strain rate (along periodic axes only); ``servo``: None,
    ``(p0 [Pa], gain [1/(Pa s)], max_rate [1/s])`` for an isotropic pressure control, or the dict of
    ``triaxial_servo`` (axial rate imposed, lateral stresses held at ``-pc``).
    ``dimension``: 3, or 2 for the 2D mode (module docstring: z not periodic, ``length[2]`` the
    thickness of the stress convention). ``shear_rate`` [3] [1/s]: ``(dv_x/dy, dv_x/dz, dv_y/dz)``
    of simple shear; ``tilt`` [3] [m]: ``(xy, xz, yz)`` of the tilted cell, each within half its
    edge (module docstring); both need the two axes they couple periodic.
    """

    def __init__(self, lo, length, periodic, rate=(0.0, 0.0, 0.0), servo=None, dimension=3,
                 shear_rate=(0.0, 0.0, 0.0), tilt=(0.0, 0.0, 0.0)):
        self.lo = vector3("cell.lo", lo, "[m] (the box's lower corner)").copy()
        self.length = vector3("cell.length", length, "[m]").copy()
        self.periodic = _flags("cell.periodic", periodic)
        self.rate = vector3("cell.rate", rate, "[1/s]").copy()
        if isinstance(dimension, (bool, np.bool_)) or not is_real(dimension) or dimension not in (2, 3):
            raise ValueError(f"cell dimension = {short(dimension)}: expected 2 or 3")
        self.dimension = int(dimension)
        if self.dimension == 2 and self.periodic[2]:
            raise ValueError("a 2D cell is not periodic along z (the grains lie in the plane z = 0)")
        if np.any(self.rate[~self.periodic] != 0.0):
            raise ValueError("cell.rate: a strain rate needs a periodic axis (non-periodic axes take 0)")
        if not np.all(self.length > 0.0):
            raise ValueError(f"cell.length must be positive along every axis, got {list(self.length)}: "
                             f"expected 3 finite edges in (0, inf) [m]")
        self.shear_rate = vector3("cell.shear_rate", shear_rate, "[1/s] (dv_x/dy, dv_x/dz, dv_y/dz)").copy()
        self.tilt = vector3("cell.tilt", tilt, "[m] (xy, xz, yz)").copy()
        for c, (a, b) in enumerate(TILT_AXES):
            name = ("xy", "xz", "yz")[c]
            if (self.shear_rate[c] != 0.0 or self.tilt[c] != 0.0) and not (self.periodic[a] and self.periodic[b]):
                raise ValueError(f"cell.shear_rate / cell.tilt {name}: simple shear {name} needs a cell periodic "
                                 f"along {'xyz'[a]} and {'xyz'[b]}")
            if not abs(self.tilt[c]) <= 0.5 * self.length[a] * (1.0 + 1e-12):
                raise ValueError(f"cell.tilt {name} = {self.tilt[c]!r} m: expected |{name}| <= half the "
                                 f"{'xyz'[a]} edge, {0.5 * self.length[a]:.6g} m (a tilt flips beyond it)")
        if servo is None:
            self.servo = None
        elif isinstance(servo, dict) and servo.get("kind") == "normal":
            self.servo = self.normal_servo(**{k: v for k, v in servo.items() if k != "kind"})
            if not self.periodic[self.servo["axis"]] or self.servo["axis"] >= self.dimension:
                raise ValueError(f"a normal-stress servo needs a periodic in-plane axis, got axis "
                                 f"{self.servo['axis']}")
        elif isinstance(servo, dict):
            if not all(isinstance(k, str) for k in servo):
                raise ValueError(f"cell.servo = {short(servo)}: a triaxial servo's keys are names (strings)")
            self.servo = self.triaxial_servo(**{k: v for k, v in servo.items() if k != "kind"})
            if self.dimension == 2:
                if self.servo["axis"] == 2:
                    raise ValueError("a biaxial (2D) servo loads axis 0 or 1, not z")
                if not np.all(self.periodic[:2]):
                    raise ValueError("a biaxial (2D) servo needs a cell periodic along x and y")
            elif not np.all(self.periodic):
                raise ValueError("a triaxial servo needs a cell periodic along every axis")
        else:
            if not (isinstance(servo, (list, tuple)) or isinstance(servo, np.ndarray) and servo.ndim == 1) \
                    or len(servo) != 3:
                raise ValueError(f"cell.servo = {short(servo)}: expected None, (p0 [Pa], gain [1/(Pa s)], "
                                 "max_rate [1/s]) or the dict of PeriodicCell.triaxial_servo")
            real("cell.servo p0", servo[0], unit="[Pa]", note="target pressure")
            real("cell.servo gain", servo[1], lo=0.0, unit="[1/(Pa s)]")
            real("cell.servo max_rate", servo[2], lo=0.0, unit="[1/s]")
            self.servo = tuple(float(v) for v in servo)
        self.servo_stiffness = 0.0   # S [Pa] of the isotropic servo's gain cap (0: no cap)
        self.strain = np.zeros(3)   # accumulated log strain of the edges since the start
        self.strain_since_build = 0.0   # largest |strain| increment since the last list build
        self.shear_strain = np.zeros(3)   # accumulated engineering shear strains (xy, xz, yz) since the start
        self.flips = 0                    # tilt flips since the start

    @property
    def hi(self):
        return self.lo + self.length

    @property
    def volume(self):
        """Cell volume [m^3]: ``L_x L_y L_z``; in 2D ``L_x L_y t`` (``t = length[2]``, the thickness)."""
        return float(np.prod(self.length))

    @property
    def area(self):
        """In-plane area ``L_x L_y`` [m^2] (the 2D cell's measure)."""
        return float(self.length[0] * self.length[1])

    @property
    def thickness(self):
        """The 2D stress convention's thickness ``t = length[2]`` [m] (2D cells)."""
        return float(self.length[2])

    def pressure(self, stress):
        """Mean compressive stress [Pa] of a stress tensor [3, 3] (tension positive):
        ``-trace / 3`` in 3D, ``-(s_xx + s_yy) / 2`` in 2D."""
        s = np.asarray(stress)
        if self.dimension == 2:
            return -(float(s[0][0]) + float(s[1][1])) / 2.0
        return -float(np.trace(s)) / 3.0

    @property
    def deforming(self):
        return self.servo is not None or any_rate(self.rate) or self.sheared

    @property
    def sheared(self):
        """Whether the cell shears (a non-zero ``shear_rate``)."""
        return any_rate(self.shear_rate)

    @property
    def tilted(self):
        """Whether the cell is tilted (a non-zero ``tilt``)."""
        return any_rate(self.tilt)

    @property
    def edges(self):
        """The edge vectors as the columns of ``H`` [3, 3] [m] (upper triangular)."""
        xy, xz, yz = self.tilt
        L = self.length
        return np.array([[L[0], xy, xz], [0.0, L[1], yz], [0.0, 0.0, L[2]]])

    @property
    def widths(self):
        """Distances between opposite faces [3] [m] (the edges when the cell is not tilted): the
        periods a neighbour search and a contact reach must respect."""
        if not self.tilted:
            return self.length.copy()
        return 1.0 / np.linalg.norm(np.linalg.inv(self.edges), axis=1)

    def gradient(self):
        """The velocity gradient as ``(g_x, g_y, g_z, g_xy, g_xz, g_yz)`` [6] [1/s] (the contact
        kernels' ``rate`` of a shearing cell)."""
        return np.concatenate([self.rate, self.shear_rate])

    def slab_axis_allowed(self, axis):
        """Whether slabs cut along ``axis`` stay slabs of the cell: no tilt or shear moves that
        coordinate with another one (x: ``xy = xz = 0``; y: ``yz = 0``; z always)."""
        coupled = [c for c, (a, _) in enumerate(TILT_AXES) if a == axis]
        return all(self.tilt[c] == 0.0 and self.shear_rate[c] == 0.0 for c in coupled)

    def deform(self, elements, dt, references=()):
        """Map the owned rows and the ``references`` position arrays affinely over one step;
        returns the step's stretch factor per axis [3] (None when the cell does not deform)."""
        if not self.deforming:
            return None
        factor = 1.0 + self.rate * dt
        if self.sheared:
            return self._shear(elements, dt, references, factor)
        _affine_map(elements.x, elements.n_owned, self.lo, factor)
        for ref in references:
            if ref is not None:
                _affine_map(ref, ref.shape[0], self.lo, factor)
        if self.tilted:   # H <- diag(factor) H
            self.tilt *= factor[[0, 0, 1]]
        self.length *= factor
        self.strain += np.log(factor)
        self.strain_since_build += float(np.max(np.abs(np.log(factor))))
        return factor

    def _shear(self, elements, dt, references, factor):
        """``deform`` with a shear rate: ``x <- lo + (1 + Lv dt)(x - lo)``, ``H <- (1 + Lv dt) H``,
        then the flips (module docstring)."""
        sxy, sxz, syz = (float(g) * dt for g in self.shear_rate)
        _shear_map(elements.x, elements.n_owned, self.lo, factor, sxy, sxz, syz)
        for ref in references:
            if ref is not None:
                _shear_map(ref, ref.shape[0], self.lo, factor, sxy, sxz, syz)
        L = self.length
        xy, xz, yz = self.tilt
        self.tilt = np.array([factor[0] * xy + sxy * L[1], factor[0] * xz + (sxy * yz + sxz * L[2]),
                              factor[1] * yz + syz * L[2]])
        self.length *= factor
        self.strain += np.log(factor)
        self.shear_strain += (sxy, sxz, syz)
        # |(1 + Lv dt) d - d| <= (max |factor - 1| + |shear part|_F) |d|: the pair distances' change
        self.strain_since_build += float(np.max(np.abs(np.log(factor)))) + float(np.sqrt(sxy * sxy + sxz * sxz
                                                                                      + syz * syz))
        self._flip()
        return factor

    def _flip(self):
        """LAMMPS' flip: a tilt beyond half its edge moves by one edge (yz first, which moves xz
        by xy); the rows keep their positions, the list must be rebuilt (its image labels)."""
        L, t = self.length, self.tilt
        flipped = False
        if abs(t[2]) > 0.5 * L[1]:
            s = np.sign(t[2])
            t[2] -= s * L[1]
            t[1] -= s * t[0]
            flipped = True
        for c in (1, 0):
            if abs(t[c]) > 0.5 * L[0]:
                t[c] -= np.sign(t[c]) * L[0]
                flipped = True
        if flipped:
            self.flips += 1
            self.strain_since_build = np.inf

    def wrap(self, elements):
        """Bring the owned rows into ``[lo, lo + L)`` along the periodic axes (at list rebuilds);
        in a tilted cell, their fractional coordinates into [0, 1)."""
        if self.tilted:
            _wrap_tilted(elements.x, elements.n_owned, self.lo, self.length, self.tilt, self.periodic)
            return
        _wrap(elements.x, elements.n_owned, self.lo, self.length, self.periodic)

    def shift_metres(self, shifts):
        """Image shifts of a pair list [n, 3] int8 in metres for the current edges: ``H @ shifts``
        (grouped as the neighbour search: ``(n_x L_x + n_y xy) + n_z xz``, ``n_y L_y + n_z yz``)."""
        s = shifts * np.where(self.periodic, self.length, 0.0)
        if self.tilted:
            xy, xz, yz = self.tilt
            s[:, 0] = (s[:, 0] + shifts[:, 1] * xy) + shifts[:, 2] * xz
            s[:, 1] = s[:, 1] + shifts[:, 2] * yz
        return s

    @staticmethod
    @keywords("PeriodicCell.triaxial_servo")
    def triaxial_servo(axis, axial_rate, pressure, gain, max_rate):
        """The ``servo`` of a triaxial test: ``axis`` (0, 1, 2) deforms at ``axial_rate`` [1/s]
        (negative: compression), the two other axes hold their normal stress at ``-pressure``
        [Pa] (``pressure`` = pc > 0, compression) with ``gain`` [1/(Pa s)], ``|rate| <= max_rate``
        [1/s]."""
        if not is_real(axis) or axis not in (0, 1, 2):
            raise ValueError(f"triaxial servo: axis = {short(axis)}: expected 0, 1 or 2")
        axis = int(axis)
        real("triaxial servo: axial_rate", axial_rate, unit="[1/s]", note="negative: compression")
        real("triaxial servo: pressure", pressure, lo=0.0, lo_open=False, unit="[Pa]")
        real("triaxial servo: gain", gain, lo=0.0, unit="[1/(Pa s)]")
        real("triaxial servo: max_rate", max_rate, lo=0.0, unit="[1/s]")
        return {"kind": "triaxial", "axis": axis, "axial_rate": float(axial_rate),
                "pressure": float(pressure), "gain": float(gain), "max_rate": float(max_rate)}

    @staticmethod
    @keywords("PeriodicCell.normal_servo")
    def normal_servo(axis, pressure, gain, max_rate):
        """The ``servo`` of simple shear at constant normal stress: ``axis`` (0, 1, 2) holds its
        normal stress at ``-pressure`` [Pa] (compression positive) with ``gain`` [1/(Pa s)],
        ``|rate| <= max_rate`` [1/s]; the other edges stay."""
        if not is_real(axis) or isinstance(axis, (bool, np.bool_)) or axis not in (0, 1, 2):
            raise ValueError(f"normal servo: axis = {short(axis)}: expected 0, 1 or 2")
        real("normal servo: pressure", pressure, lo=0.0, lo_open=False, unit="[Pa]")
        real("normal servo: gain", gain, lo=0.0, unit="[1/(Pa s)]")
        real("normal servo: max_rate", max_rate, lo=0.0, unit="[1/s]")
        return {"kind": "normal", "axis": int(axis), "pressure": float(pressure), "gain": float(gain),
                "max_rate": float(max_rate)}

    def control(self, stress, dt=0.0):
        """Servo update of ``rate`` from the global stress tensor [3, 3] [Pa] (tension positive);
        ``dt`` [s] the step the rate will act over (for the isotropic servo's gain cap)."""
        if self.servo is None:
            return
        if isinstance(self.servo, dict) and self.servo["kind"] == "normal":
            sv = self.servo
            a = sv["axis"]
            g = sv["gain"] * (-float(stress[a][a]) - sv["pressure"])
            rate = np.zeros(3)
            rate[a] = min(max(g, -sv["max_rate"]), sv["max_rate"])
            self.rate = rate
            return
        if isinstance(self.servo, dict):
            sv = self.servo
            rate = np.zeros(3)
            for b in range(self.dimension):
                if b == sv["axis"]:
                    rate[b] = sv["axial_rate"]
                else:
                    g = sv["gain"] * (-float(stress[b][b]) - sv["pressure"])
                    rate[b] = min(max(g, -sv["max_rate"]), sv["max_rate"])
            self.rate = rate
            return
        p0, gain, max_rate = self.servo
        if self.servo_stiffness > 0.0 and dt > 0.0:
            gain = min(gain, 0.5 / (self.servo_stiffness * dt))
        p = self.pressure(stress)
        g = float(np.clip(gain * (p - p0), -max_rate, max_rate))
        self.rate = np.where(self.periodic, g, 0.0)

    def state(self):
        """Everything needed to restart the cell (JSON friendly)."""
        return {"lo": self.lo.tolist(), "length": self.length.tolist(),
                "periodic": self.periodic.tolist(), "rate": self.rate.tolist(),
                "servo": (None if self.servo is None else dict(self.servo)
                          if isinstance(self.servo, dict) else list(self.servo)),
                "strain": self.strain.tolist(), "strain_since_build": self.strain_since_build,
                "servo_stiffness": self.servo_stiffness, "dimension": self.dimension,
                "shear_rate": self.shear_rate.tolist(), "tilt": self.tilt.tolist(),
                "shear_strain": self.shear_strain.tolist(), "flips": self.flips}

    @classmethod
    def from_state(cls, s):
        cell = cls(s["lo"], s["length"], s["periodic"], s["rate"], s["servo"],
                   dimension=int(s.get("dimension", 3)), shear_rate=s.get("shear_rate", (0.0, 0.0, 0.0)),
                   tilt=s.get("tilt", (0.0, 0.0, 0.0)))
        cell.shear_strain = np.asarray(s.get("shear_strain", (0.0, 0.0, 0.0)), dtype=np.float64)
        cell.flips = int(s.get("flips", 0))
        cell.strain = np.asarray(s["strain"], dtype=np.float64)
        cell.strain_since_build = float(s["strain_since_build"])
        cell.servo_stiffness = float(s.get("servo_stiffness", 0.0))
        return cell
