"""``sim.particles`` and the global reactions on any number of ranks (tests/test_particles.py).

    python particles_run.py OUT_DIR        (or under mpiexec -n 2)

Writes ``OUT_DIR/particles.npz`` from rank 0 (arrays read through ``sim.particles`` on every rank,
after each rank checked that it read the same bits as every other rank) and, for the checkpoint
test, ``OUT_DIR/gas.h5``:

* ``set_*``: a frictional Hertz gas in a periodic cell built at X0, its positions, velocities and
  spins then set to X1, V1, W1 and a custom scalar and [N, 2] property set, run; ``built_*``: the
  same gas built at X1, V1, W1, run; the bulk drift along the slab axis makes elements migrate
  (``owner_before``, ``owner_after``: the rank owning each gid);
* ``late_*``: a frictionless gas built at X0, run, then set to X1, V1, W1 and identity
  orientations and run; ``fresh_*``: built at X1, V1, W1, run (no tangential spring: the state
  set after a run is the whole state);
* ``loaded_*``: the gas's checkpoint read back on the same rank count;
* cantilever, resting spheres and a driven row: the global reactions and wall forces as every
  rank holds them.
"""
import os
import sys

import numpy as np

import pardem

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from _util import bonded_sim, granular_case  # noqa: E402
from pardem.engine import granular

out_dir = sys.argv[1]
comm = pardem.Communicator()
out = {}


def same_everywhere(name, a):
    """Store ``a`` after checking that every rank holds the same bits."""
    a = np.asarray(a)
    got = comm.allgather(a.tobytes())
    assert all(g == got[0] for g in got), f"{name}: the ranks read different values"
    out[name] = a


def owners(sim):
    """The rank owning each gid [N] (from the local views, gathered once)."""
    mine = sim.particles.local.gids
    g = comm.allgatherv(np.ascontiguousarray(mine))
    r = comm.allgatherv(np.full(len(mine), comm.rank, dtype=np.int64))
    return r[np.argsort(g)]


# -- a gas: set-then-run against built, migration of custom arrays, checkpoint ------------------
R = 0.1e-3
pos0, L = granular.simple_cubic(5, R, spacing=2.1, jitter=0.02, seed=7)
pos1, _ = granular.simple_cubic(5, R, spacing=2.1, jitter=0.02, seed=8)
# squeezed about the centre (spacing 2.0 R: pairs in contact at once) and shuffled (every element
# elsewhere: it migrates at the set)
pos1 = 0.5 * L + (pos1 - 0.5 * L) * (2.0 / 2.1)
pos1 = pos1[np.random.default_rng(2).permutation(len(pos1))]
rng = np.random.default_rng(3)
V1 = rng.normal(0.0, 3.0, pos1.shape) + np.array([40.0, 0.0, 0.0])    # drift across the slabs (x)
W1 = rng.normal(0.0, 3e4, pos1.shape)
HM = {"young": 72e9, "poisson": 0.2, "friction": 0.5, "restitution": 0.9}
STEPS = 600
DT = 1e-8


def gas(x, params, **kw):
    return granular_case(comm, x, R, 2500.0, "hertz_mindlin", params, np.zeros(3), np.full(3, L),
                                  skin=None, dt=DT, slab_axis=0, **kw).sim


N = len(pos0)
temperature = 300.0 + np.arange(N, dtype=float)            # a value per gid
tag = np.stack([np.arange(N, dtype=float), -np.arange(N, dtype=float)], axis=1)

a = gas(pos0, HM)
p = a.particles
p.add_property("temperature", default=-1.0)
p.add_property("tag", shape=(2,))
p.set("temperature", temperature)
p.set("tag", tag[::-1], gids=np.arange(N)[::-1])            # any gid order
p.set("positions", pos1)
p.set("velocities", V1)
p.set("angular_velocities", W1)
same_everywhere("owner_before", owners(a))
a.run(STEPS)
same_everywhere("owner_after", owners(a))
for name in ("positions", "velocities", "angular_velocities", "orientations", "forces", "torques", "radii",
             "masses", "gids", "temperature", "tag"):
    same_everywhere(f"set_{name}", a.particles.get(name))
same_everywhere("set_subset", a.particles.get("positions", [7, 3, 7]))
same_everywhere("set_n", a.particles.n)
# every row a rank holds, ghosts included, carries its gid's custom values
e = a.elements
held = bool(np.array_equal(e.properties["temperature"], temperature[e.gid])
            and np.array_equal(e.properties["tag"], tag[e.gid]))
same_everywhere("ghosts_hold_properties", comm.allgather(held))
same_everywhere("ghost_count", comm.sum(float(e.n_total - e.n_owned)))
path = os.path.join(out_dir, "gas.h5")
pardem.save(a, path)
back = pardem.load(comm, path)
for name in ("positions", "velocities", "temperature", "tag"):
    same_everywhere(f"loaded_{name}", back.particles.get(name))

b = gas(pos1, HM, velocities=V1, angular_velocities=W1)
b.run(STEPS)
for name in ("positions", "velocities", "angular_velocities", "orientations", "forces", "torques"):
    same_everywhere(f"built_{name}", b.particles.get(name))

# -- set after a run (no tangential spring) ----------------------------------------------------
FRICTIONLESS = {**HM, "friction": 0.0}
c = gas(pos0, FRICTIONLESS, velocities=rng.normal(0.0, 3.0, pos0.shape))
c.run(200)
identity = np.tile([1.0, 0.0, 0.0, 0.0], (N, 1))
for name, values in (("positions", pos1), ("velocities", V1), ("angular_velocities", W1),
                     ("orientations", identity)):
    c.particles.set(name, values)
same_everywhere("late_forces_at_set", c.particles.forces)
c.run(STEPS)
d0 = gas(pos1, FRICTIONLESS, velocities=V1, angular_velocities=W1)
d0.run(0)      # a system of its own: a second run from step 0 would add the initial forces again
same_everywhere("fresh_forces_at_start", d0.particles.forces)
d = gas(pos1, FRICTIONLESS, velocities=V1, angular_velocities=W1)
d.run(STEPS)
for name in ("positions", "velocities", "angular_velocities", "orientations", "forces"):
    same_everywhere(f"late_{name}", c.particles.get(name))
    same_everywhere(f"fresh_{name}", d.particles.get(name))

# -- a cantilever: the clamp's reaction against the load ---------------------------------------
n, RC, F = 6, 0.01, 1e-3
x = np.zeros((n, 3))
x[:, 0] = 2.0 * RC * np.arange(n)
pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
material = pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0)
L_c = 2.0 * RC * (n - 1)
EI = 1e9 * np.pi * (0.5 * RC) ** 4 / 4.0
m = 1000.0 * 4.0 / 3.0 * np.pi * RC**3
omega1 = 1.875**2 * np.sqrt(EI / (m / (2.0 * RC) * L_c**4))
cant = bonded_sim(comm, x, RC, 1000.0, pairs, material, viscous_damping=2.0 * omega1)
clamp = pardem.Clamp([0])
load = np.array([2e-4, -3e-4, -F])
pardem.add_fixes(cant, clamp, pardem.ExternalForce([n - 1], force=load))
chunk = max(1, int(5.0 / omega1 / cant.dt))
tips = []
for _ in range(60):
    cant.run(chunk)
    tips.append(cant.particles.get("positions", [n - 1])[0])
    if len(tips) >= 3 and np.max(np.abs(tips[-1] - tips[-2])) < 1e-12 * L_c:
        break
same_everywhere("cantilever_positions", cant.particles.positions)
same_everywhere("cantilever_reaction", clamp.global_reaction)
same_everywhere("cantilever_reaction_torque", clamp.global_reaction_torque)
same_everywhere("cantilever_local_sum", comm.sum(np.concatenate([clamp.reaction, clamp.reaction_torque])))
out["cantilever_load"] = load
if comm.rank == comm.size - 1:
    # read on one rank only (the last, which may own no clamped element): no collective, no hang
    out_last = clamp.global_reaction.copy()
    comm.comm.send(out_last, dest=0, tag=5) if comm.size > 1 else out.update(cantilever_last_rank=out_last)
if comm.rank == 0 and comm.size > 1:
    out["cantilever_last_rank"] = comm.comm.recv(source=comm.size - 1, tag=5)

# -- spheres resting on a floor: the wall force is their weight --------------------------------
RS, RHO, K, G = 0.01, 2500.0, 1e4, 9.81
radii = RS * np.array([1.0, 0.8, 1.2, 0.9])
xs = np.stack([3.0 * RS * np.arange(4), np.zeros(4), radii], axis=1)
masses = RHO * 4.0 / 3.0 * np.pi * radii**3
omega = np.sqrt(K / masses.min())
rest = bonded_sim(comm, xs, radii, RHO, np.zeros((0, 2), int), material, viscous_damping=2.0 * omega,
                            walls=dict(normals=[[0, 0, 1]], points=[[0, 0, 0]], stiffness=K))
pardem.add_fixes(rest, pardem.Gravity((0.0, 0.0, -G)))
rest.run(3000)
same_everywhere("rest_wall_force", rest.plates.force)
same_everywhere("rest_wall_normal_force", rest.plates.normal_force)
same_everywhere("rest_wall_forces_collective", rest.plates.forces(comm))
same_everywhere("rest_masses", rest.particles.masses)
out.update(rest_C=2.0 * omega, rest_dt=rest.dt, rest_z=xs[:, 2])

# -- a driven row against viscous drag: the drive's reaction is the drag ------------------------
C, V = 50.0, np.array([0.3, -0.2, 0.1])
row = bonded_sim(comm, xs, radii, RHO, np.zeros((0, 2), int), material, dt=1e-4, viscous_damping=C,
                           velocities=np.tile(V, (4, 1)))
drive = pardem.PrescribedVelocity(np.arange(4), V, angular_velocity=(0.0, 0.0, 2.0))
pardem.add_fixes(row, drive)
row.run(10)
same_everywhere("drive_reaction", drive.global_reaction)
same_everywhere("drive_reaction_torque", drive.global_reaction_torque)
same_everywhere("drive_masses", row.particles.masses)
same_everywhere("drive_radii", row.particles.radii)

out["ranks"] = comm.size
if comm.rank == 0:
    np.savez(os.path.join(out_dir, "particles.npz"), **out)
