"""Planar walls for any ``Simulation``: static or moving at constant velocity.

``Walls`` is a set of infinite planes sharing one element-wall law (``pardem.physics.walls.Params``,
linear or Hertz, optional friction and restitution). It has the interface ``Simulation`` uses for
``sim.plates`` (``planes(time)``, ``move_to(time)``, ``law``, ``wall_force``, ``force_local``), so the
time loop and the compiled wall kernel (``pardem.physics.walls.compute``) are the same as for the
compression test's plates (``pardem.engine.state.Plates``). A Simulation holds one wall set.

A wall is given by a point ``p`` on it and its unit normal ``n`` pointing **into** the domain (towards
the elements): the plane is ``{x : n . x = n . p}``. An element of radius R touches it when its centre
is closer than R to the plane. A wall may translate at a constant velocity ``V`` [m/s]: its plane at
time t is ``n . x = n . p + n . V (t - t_add)`` (``t_add`` = the simulation time when it was added); the
tangential part of ``V`` moves the surface in its own plane (a conveyor: it drags the elements through
friction). Walls do not rotate.

``add_walls(sim, normals, points, ...)`` builds the set, gives the elements their wall history
(``elements.wall_h``, [n_rows, n_walls, 3] with friction, [n_rows, 0, 3] without; it migrates with the
elements between ranks), attaches it as ``sim.plates`` and checks ``sim.dt`` against the critical time
step with the walls' stiffness (``pardem.engine.critical_step.critical_time_step_of``).

``walls.force`` [n_walls, 3] [N] is the total force of the elements **on** each wall and
``walls.normal_force`` [n_walls] [N] its compressive part ``-F . n`` (positive when the elements
push the wall): plain arrays, the same on every rank, as of the last step after which an operation
ran, or the end of the last ``sim.run`` (``Simulation._reduce_globals`` reduces them there, one
allreduce with the fixes' reactions; ``pardem.engine.particles.reduce_globals``). Reading them
needs no collective, so a script may do it on one rank. ``walls.forces(comm)`` and
``normal_forces(comm)`` are the same sums of the last step, collective. Each element's wall load
depends on that element alone, so the trajectories are the same bits on any number of ranks (with
reproducible contacts); the total is a floating-point sum over the rows, then over the ranks, so it
agrees between decompositions to the round-off of that sum (about ``n eps sum_k |F_k|``), not bit
for bit.

Domain (``check_domain``, at ``add_walls``): in a cell no wall normal may have a component along a
periodic axis (elements would wrap through the wall). In the 2D mode (``pardem.engine.plane``) a
wall is a line of the plane z = 0: its normal and its velocity have no z component. The kernel is
the 3D one; for grains in the plane (``v_z = w_x = w_y = 0``) the contact point, the relative
velocity, the friction force lie in the plane and the torque is along z, so a 2D run with walls is
the 3D run of the same planar configuration bit for bit (``tests/test_two_d_walls_cement.py``).
"""
import math

import numpy as np

from pardem.engine.critical_step import critical_time_step_of
from pardem.physics import walls as wall_kernels
from pardem.physics.arguments import array, keywords, real, short

WALL_OVERLAP_BOUND = 0.05   # Hertz walls: the critical time step holds up to this overlap / R


@keywords("Walls")
class Walls:
    """Planar walls (see the module docstring).

    normals [n, 3] : inward unit normals (normalised here; must be non-zero); points [n, 3] [m] : a
    point on each wall; velocities [n, 3] [m/s] : constant translation velocities (default 0);
    law : ``pardem.physics.walls.Params``; time0 [s] : the time at which the walls are at ``points``.
    """

    def __init__(self, normals, points, law, velocities=None, time0=0.0):
        normals = array("normals", normals).copy()
        if normals.ndim == 1:
            normals = normals.reshape(1, -1)
        if normals.ndim != 2 or normals.shape[1] != 3 or normals.shape[0] < 1:
            raise ValueError(f"normals must have shape (n_walls, 3) with n_walls >= 1, got {normals.shape}")
        n = normals.shape[0]
        with np.errstate(over="ignore"):   # an overflowing norm is refused below
            length = np.linalg.norm(normals, axis=1)
        if not np.all(np.isfinite(length)) or np.any(length <= 0.0):
            raise ValueError(f"normals must be finite non-zero vectors (inward wall normals), got {normals.tolist()}")
        normals /= length[:, None]
        # exact axis-aligned normals let the kernel read one coordinate per row
        aligned = np.isclose(np.abs(normals), 1.0, rtol=0, atol=1e-15)
        normals[aligned] = np.sign(normals[aligned])
        points = array("points", points, "[m]").copy()
        if points.shape == (3,) and n == 1:
            points = points.reshape(1, 3)
        if points.shape != (n, 3) or not np.all(np.isfinite(points)):
            raise ValueError(f"points must be finite with shape ({n}, 3) (one point per wall) [m], got "
                             f"shape {np.shape(points)}")
        vel = np.zeros((n, 3)) if velocities is None else array("velocities", velocities, "[m/s]").copy()
        if vel.shape == (3,):
            vel = np.tile(vel, (n, 1))
        if vel.shape != (n, 3) or not np.all(np.isfinite(vel)):
            raise ValueError(f"velocities must be finite with shape (3,) or ({n}, 3) [m/s], got shape "
                             f"{vel.shape}")
        if not isinstance(law, wall_kernels.Params):
            raise ValueError(f"law must be a pardem.physics.walls.Params, got {type(law).__name__}")
        real("time0", time0, unit="[s]")
        self.law = law
        self.normals = np.ascontiguousarray(normals)
        self.offsets0 = np.einsum("wd,wd->w", normals, points)
        self.velocities = np.ascontiguousarray(vel)
        self.time0 = float(time0)
        self.offsets = self.offsets0.copy()
        self.wall_force = np.zeros((n, 3))    # this rank's share of the last step [N]
        self.force = np.zeros((n, 3))         # the global total, reduced by ``sim.run`` [N]
        # Simulation stores the compressive force of the first two walls here (Plates' interface)
        self.force_local = np.zeros(min(n, 2))

    @property
    def n_walls(self) -> int:
        return self.normals.shape[0]

    def offsets_at(self, time):
        """Plane offsets [n_walls] [m] at ``time`` [s] (``n . x = offset``)."""
        return self.offsets0 + np.einsum("wd,wd->w", self.normals, self.velocities) * (time - self.time0)

    def move_to(self, time):
        self.offsets[:] = self.offsets_at(time)

    def planes(self, time):
        """``(normals [n, 3], offsets [n], velocities [n, 3])`` for ``pardem.physics.walls``."""
        return self.normals, self.offsets, self.velocities

    def positions(self):
        """A point on each wall now [n_walls, 3] [m] (the foot of the origin's normal)."""
        return self.normals * self.offsets[:, None]

    @property
    def normal_force(self):
        """Compressive normal force on each wall [n_walls] [N] (``-force . n``) from ``self.force``:
        global, as of the last reduction (module docstring); no collective."""
        return -np.einsum("wd,wd->w", self.force, self.normals)

    def forces(self, comm):
        """Total force of the elements on each wall [n_walls, 3] [N] at the last step (collective;
        a float sum, so decompositions agree to its round-off: module docstring)."""
        return np.asarray(comm.sum(self.wall_force)).reshape(-1, 3)

    def normal_forces(self, comm):
        """Compressive normal force on each wall [n_walls] [N] (``-F . n``; collective)."""
        return -np.einsum("wd,wd->w", self.forces(comm), self.normals)

    def stiffness(self, radius):
        """Normal stiffness [N/m] used for the critical time step of elements of ``radius`` [m]
        (Hertz: the tangent stiffness at an overlap of ``WALL_OVERLAP_BOUND`` R)."""
        if self.law.law == "hertz":
            return max(wall_kernels.stiffness(self.law, radius, WALL_OVERLAP_BOUND * radius))
        return max(wall_kernels.stiffness(self.law, radius, 0.0))


@keywords("wall_law")
def wall_law(law="linear", stiffness=None, young=None, poisson=None, restitution=1.0, friction=0.0,
             wall_young=None, **extra):
    """``pardem.physics.walls.Params`` from keywords: linear law with ``stiffness`` [N/m], or Hertz
    with the elements' ``young`` [Pa] and ``poisson`` against a wall of ``wall_young`` [Pa] (None:
    ``math.inf``, rigid). ``extra``: the other keywords of ``walls.Params`` (``kt``, ``tangential_damping`` for the
    linear law, ``wall_poisson`` for Hertz). ValueError naming the argument for a bad value, an
    unknown keyword or one of the other law."""
    if not isinstance(law, str) or law not in ("linear", "hertz"):
        raise ValueError(f"law = {short(law)}: expected 'linear' or 'hertz' (or a pardem.physics.walls.Params)")
    own = {"linear": ("stiffness", "kt", "tangential_damping"),
           "hertz": ("young", "poisson", "wall_young", "wall_poisson")}
    names = ("law", "stiffness", "young", "poisson", "restitution", "friction", "wall_young",
             "kt", "wall_poisson", "tangential_damping")
    for key in extra:
        if key not in names:
            raise ValueError(f"wall_law() got an unexpected keyword {key!r}: valid names are {', '.join(names)}")
    given = {"stiffness": stiffness, "young": young, "poisson": poisson, "wall_young": wall_young, **extra}
    other = own["hertz" if law == "linear" else "linear"]
    for key in other:
        if given.get(key) is not None:
            raise ValueError(f"{key} = {short(given[key])} applies to law = "
                             f"{'hertz' if law == 'linear' else 'linear'!r} only, not to law = {law!r}")
    if law == "linear":
        try:
            real("stiffness", stiffness, lo=0.0, unit="[N/m]")
        except ValueError:
            raise ValueError(f"stiffness must be a positive number [N/m] for a linear wall law (in (0, inf)), "
                             f"got {short(stiffness)}") from None
        return wall_kernels.Params(law="linear", kn=stiffness, restitution=restitution, friction=friction,
                                   **extra)
    return wall_kernels.Params(law="hertz", young=young, poisson=poisson,
                               wall_young=math.inf if wall_young is None else wall_young,
                               restitution=restitution, friction=friction, **extra)


def add_walls(sim, normals, points, velocities=None, law="linear", check_dt=True, **law_keywords):
    """Add a set of planar walls to ``sim`` (every rank, same arguments) and return it (``Walls``).

    normals [n, 3] (inward), points [n, 3] [m], velocities [3] or [n, 3] [m/s] (default static);
    law : a ``pardem.physics.walls.Params``, or ``"linear"`` / ``"hertz"`` with the keywords of
    ``wall_law`` (``stiffness=``, ``young=``, ``poisson=``, ``restitution=``, ``friction=``).
    ``check_dt``: raise ValueError when ``sim.dt`` is above the critical time step with the walls.
    ValueError if ``sim`` already has walls or plates (one wall set per Simulation).
    """
    if sim.plates is not None:
        raise ValueError("this Simulation already has walls (sim.plates): put every wall in one "
                         "add_walls call (one wall set, one law)")
    params = law if isinstance(law, wall_kernels.Params) else wall_law(law, **law_keywords)
    if isinstance(law, wall_kernels.Params) and law_keywords:
        raise ValueError(f"law is already a walls.Params: the keywords {sorted(law_keywords)} are not used")
    w = Walls(normals, points, params, velocities, time0=sim.step_count * sim.dt)
    check_domain(sim, w)
    if check_dt:
        dt_c = critical_time_step_of(sim, walls=w)
        if not sim.dt <= dt_c:
            raise ValueError(f"sim.dt = {sim.dt:.6g} s is above the critical time step {dt_c:.6g} s with "
                             f"these walls (stiffness {w.stiffness(_max_radius(sim)):.4g} N/m): lower the "
                             f"wall stiffness or the time step (sim.set_dt) to at most {dt_c:.6g} s")
    e = sim.elements
    e.wall_h = wall_kernels.new_history(params, e.n_total, w.n_walls)
    w.move_to(sim.step_count * sim.dt)
    sim.plates = w
    return w


def check_domain(sim, walls):
    """ValueError (naming the wall) unless every wall of ``walls`` fits ``sim``'s domain: no normal
    component along a periodic axis of ``sim.cell``; in the 2D mode, normals and velocities with no
    z component (a wall is a line of the plane z = 0)."""
    from pardem.engine.plane import dimension_of
    n, v = walls.normals, walls.velocities
    if dimension_of(sim) == 2:
        for name, arr, unit in (("normals", n, ""), ("velocities", v, " [m/s]")):
            bad = np.nonzero(arr[:, 2] != 0.0)[0]
            if len(bad):
                k = int(bad[0])
                raise ValueError(f"{name}[{k}] = {arr[k].tolist()}{unit}: in 2D a wall is a line of the "
                                 "plane z = 0, its z component must be 0")
    cell = getattr(sim, "cell", None)
    if cell is not None and np.any(cell.periodic):
        bad = np.nonzero(np.any(n[:, cell.periodic] != 0.0, axis=1))[0]
        if len(bad):
            k = int(bad[0])
            axes = "".join("xyz"[a] for a in range(3) if cell.periodic[a])
            raise ValueError(f"normals[{k}] = {n[k].tolist()}: a wall normal must have no component "
                             f"along the cell's periodic axes ({axes}): elements would wrap through it")


def _max_radius(sim):
    e = sim.elements
    return float(sim.comm.max(float(e.radius[:e.n_owned].max()) if e.n_owned else 0.0))


__all__ = ["Walls", "add_walls", "wall_law", "check_domain"]
