"""Independent NumPy helpers for the tests: quaternions, rotations, small bonded systems, the free
oscillation of a bonded pair and its logarithmic decrement.

Nothing here calls pardem's quaternion code, so tests can compare pardem against it (``free_oscillation``
runs pardem's time loop: it is the system under test, its measures are this module's).
"""

import numpy as np

from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.engine.simulation import Simulation
from pardem.parallel.communicator import Communicator
from pardem.physics.beam import compute_bonds
from pardem.engine.state import Elements, Plates


def quat(rotvec):
    """Unit quaternion (w, x, y, z) of a rotation vector (axis * angle)."""
    rv = np.asarray(rotvec, dtype=float)
    a = np.linalg.norm(rv)
    if a == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[np.cos(a / 2)], np.sin(a / 2) * rv / a])


def qmul(a, b):
    """Hamilton product a * b."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def rotmat(rotvec):
    """Rotation matrix of a rotation vector (Rodrigues)."""
    rv = np.asarray(rotvec, dtype=float)
    a = np.linalg.norm(rv)
    if a == 0.0:
        return np.eye(3)
    k = rv / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * K @ K


def random_unit(rng):
    u = rng.normal(size=3)
    return u / np.linalg.norm(u)


def random_rotvec(rng, max_angle):
    return random_unit(rng) * rng.uniform(0.0, max_angle)


def perpendicular(n, rng):
    """A random unit vector normal to unit ``n``."""
    p = np.cross(n, random_unit(rng))
    return p / np.linalg.norm(p)


def relative_rotation(e, axis, k1=0, k2=1):
    """Angle [rad] about unit ``axis`` of the relative rotation q_k2 q_k1^-1 of two elements."""
    qr = qmul(e.q[k2], e.q[k1] * np.array([1.0, -1.0, -1.0, -1.0]))
    return 2.0 * np.arctan2(qr[1:] @ axis, qr[0])


def rotate_element(e, k, rotvec):
    """Rotate element ``k`` by the world-frame rotation ``rotvec`` (q <- exp(rotvec) q)."""
    e.q[k] = qmul(quat(rotvec), e.q[k])
    e.refresh_rotations()


def two_elements(n=(1.0, 0.0, 0.0), R1=1e-3, R2=1e-3, young=1e9, radius_ratio=0.5, poisson=0.3,
                 damping=0.0, density=1000.0, q1=None, q2=None, origin=(0.0, 0.0, 0.0)):
    """Two touching spheres along unit ``n`` with initial orientations q1, q2, joined by one bond."""
    n = np.asarray(n, dtype=float)
    n = n / np.linalg.norm(n)
    origin = np.asarray(origin, dtype=float)
    pos = np.array([origin, origin + (R1 + R2) * n])
    e = Elements.from_spheres(pos, np.array([R1, R2]), density)
    for k, q in enumerate((q1, q2)):
        if q is not None:
            e.q[k] = q
    e.refresh_rotations()
    mat = BeamMaterial(young=young, radius_ratio=radius_ratio, poisson=poisson, damping=damping)
    b = make_bonds(e, np.array([[0, 1]]), mat, np.eye(3))
    return e, b


def loads(bonds, e):
    """Forces [n, 3], moments [n, 3] and elastic energy of the bonds in the current state.

    Overwrites ``e.f`` and ``e.t``.
    """
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy = compute_bonds(bonds, e)[0]
    return e.f.copy(), e.t.copy(), energy


def beam_constants(R1, R2, young, radius_ratio, poisson):
    """Independent textbook section constants: (S, I, I0, G) of the bond."""
    r = radius_ratio * 0.5 * (R1 + R2)
    return np.pi * r**2, np.pi * r**4 / 4.0, np.pi * r**4 / 2.0, young / (2.0 * (1.0 + poisson))


def reduced(a, b):
    """The reduced mass (or inertia) a b / (a + b) of two bodies."""
    return a * b / (a + b)


def free_oscillation(e, b, omega_d, measure, periods=4.5, per_period=400):
    """Run the free bonded pair ``e``, ``b`` (plates far away) for ``periods`` periods of the damped
    angular frequency ``omega_d`` [rad/s], ``per_period`` steps each; returns ``measure(elements)``
    at the start and after every step [n_steps + 1], and the time step dt [s]."""
    dt = 2 * np.pi / omega_d / per_period
    sim = Simulation(Communicator(), e, b, Plates.pair(0, -1.0, 1.0, 0.0, 1.0), dt)
    out = [measure(e)]

    class Record:
        trigger = 1

        def __call__(self, sim):
            out.append(measure(sim.elements))

    sim.run(int(periods * per_period), operations=[Record()])
    return np.array(out), dt


def log_decrement_ratio(s):
    """Damping ratio from the mean logarithmic decrement delta of the maxima of the decaying signal
    ``s`` (peaks refined by a parabola through three samples): zeta = delta / sqrt(4 pi^2 + delta^2)."""
    k = np.nonzero((s[1:-1] > s[:-2]) & (s[1:-1] >= s[2:]))[0] + 1
    peaks = s[k] - 0.125 * (s[k + 1] - s[k - 1]) ** 2 / (s[k - 1] - 2 * s[k] + s[k + 1])
    assert len(peaks) >= 3
    delta = np.mean(np.log(peaks[:-1] / peaks[1:]))
    return delta / np.sqrt(4 * np.pi**2 + delta**2)


def has_matplotlib():
    try:
        import matplotlib  # noqa: F401
        return True
    except ImportError:
        return False


class FakeComm:
    """Single-rank stand-in with the Communicator verbs the engine uses."""
    size = 1
    rank = 0
    is_root = True

    def sum(self, values):
        return np.array(values, dtype=np.float64)

    def max_array(self, values):
        return np.array(values, dtype=np.float64)

    def max(self, value):
        return value

    def min(self, value):
        return value

    def any(self, flag):
        return bool(flag)

    def allgather(self, obj):
        return [obj]

    def gather(self, obj, root=0):
        return [obj]

    def bcast(self, obj, root=0):
        return obj

    def barrier(self):
        pass


EXIT_NOT_MEASURED = 5   # pardem.drivers.cli: the run ended but is too short to measure its result


def ran_to_end(p):
    """A driver subprocess ran to its last step: exit 0, or exit 5 with the one line saying the run
    was too short to measure (tests of checkpoints and restarts use short runs on purpose)."""
    return p.returncode == 0 or (p.returncode == EXIT_NOT_MEASURED and "too short to measure" in p.stderr
                                 and "Traceback" not in p.stderr)


# -- systems for the tests, described in a few arguments --------------------------------------

def granular_case(comm, positions, radii, density, law, params, box_lo, box_length, dt, skin,
                  periodic=(True, True, True), rate=(0.0, 0.0, 0.0), servo=None, viscous_damping=0.0,
                  velocities=None, angular_velocities=None, slab_axis=0, balance_every=0, dimension=3,
                  thickness=None, orientation=True, allow_overlaps=False):
    """A ``GranularCase`` of spheres in contact in a cell, through the one builder
    (``pardem.engine.system.build``): the tests' shorthand for the ``System`` it describes."""
    from pardem.engine.granular import build_case
    from pardem.engine.system import Cell, ContactModel, Decomposition, Integration, Particles, System
    system = System(Particles(positions, radii, density, velocities, angular_velocities, allow_overlaps),
                    contacts=ContactModel(law, dict(params)),
                    cell=Cell(box_lo, box_length, periodic, rate, servo, thickness),
                    integration=Integration(dt=dt, viscous_damping=viscous_damping, orientation=orientation),
                    decomposition=Decomposition(slab_axis=slab_axis, skin=skin, balance_every=balance_every),
                    dimension=dimension)
    return build_case(comm, system)


def bonded_sim(comm, positions, radii, density, pairs, material, frame=None, dt=None, dt_fraction=0.3,
               walls=None, contacts=None, viscous_damping=0.0, velocities=None, skin=None, slab_axis="auto",
               balance_every=0, max_speed=1e4):
    """A ``Simulation`` of bonded spheres (``walls``: keywords of a ``WallModel`` plus the wall law's;
    ``contacts``: ``{"law": ..., "params": {...}}``), through the one builder: the tests' shorthand."""
    from pardem.engine.system import (BondModel, ContactModel, Decomposition, Integration, Particles, System,
                                      WallModel, build)
    from pardem.engine.walls import wall_law
    wm = None
    if walls is not None:
        w = dict(walls)
        geometry = {k: w.pop(k) for k in ("normals", "points", "velocities") if k in w}
        law = w.pop("law", "linear")
        wm = WallModel(law=law if not isinstance(law, str) else wall_law(law, **w), **geometry)
    cm = None if contacts is None else ContactModel(contacts["law"], dict(contacts.get("params", {})))
    system = System(Particles(positions, radii, density, velocities),
                    bonds=BondModel(material, pairs, frame), contacts=cm, walls=wm,
                    integration=Integration(dt=dt, dt_fraction=dt_fraction, viscous_damping=viscous_damping,
                                            max_speed=max_speed),
                    decomposition=Decomposition(slab_axis=slab_axis, skin=skin, balance_every=balance_every))
    return build(comm, system)
