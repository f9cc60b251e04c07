"""A small sheared periodic packing shared by tests/test_simple_shear.py and its MPI script."""
import numpy as np

import pardem


def packing(n=400, seed=5, phi=0.55):
    """Random centres (overlaps allowed: the contacts push them apart) and radii in [0.8, 1.2] mm
    in a cube of solid fraction ``phi``: positions [n, 3], radii [n], edge [m]."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.8e-3, 1.2e-3, n)
    side = (float(np.sum(4.0 / 3.0 * np.pi * r ** 3)) / phi) ** (1.0 / 3.0)
    return rng.uniform(0.0, side, (n, 3)), r, side


def system(shear_rate=(2000.0, 0.0, 0.0), servo=None, n=400, seed=5, slab_axis="auto", friction=0.5,
           velocities=True, law="linear"):
    x, r, side = packing(n, seed)
    rng = np.random.default_rng(seed + 1)
    v = rng.normal(0.0, 0.05, (n, 3)) if velocities else None
    params = ({"kn": 2e5, "kt": 1.5e5, "friction": friction, "restitution": 0.5} if law == "linear"
              else {"young": 7e7, "poisson": 0.3, "friction": friction, "restitution": 0.5})
    return pardem.System(
        pardem.Particles(x, r, 2500.0, velocities=v, allow_overlaps=True),
        contacts=pardem.ContactModel(law, params),
        cell=pardem.Cell((0.0, 0.0, 0.0), (side, side, side), (True, True, True), shear_rate=shear_rate,
                         servo=servo),
        # the random gas's deep overlaps push grains apart at up to 0.4 radius per step in the
        # first steps (measured), above the default runaway bound of 0.1
        integration=pardem.Integration(dt=2e-6, orientation=False, max_step_displacement=1.0),
        decomposition=pardem.Decomposition(slab_axis=slab_axis, skin=0.2e-3))


def state(sim):
    """Positions, velocities, spins by gid and the cell (global, on every rank)."""
    p = sim.particles
    return {"x": p.positions, "v": p.velocities, "w": p.angular_velocities,
            "tilt": np.array(sim.cell.tilt), "length": np.array(sim.cell.length),
            "stress": np.array(sim.global_stress())}
