"""Every wall kind in one run, for the restart and rank-count tests (tests/test_wall_kinds.py).

    python wall_kinds_run.py OUT_DIR full       (or under mpiexec -n 2)
    python wall_kinds_run.py OUT_DIR restart    (reads OUT_DIR/half.h5 of a full run)

A frictional bed of spheres in a rotating drum (a cylinder along z), on a floor that shakes
(``Sinusoid``), under a force-controlled lid (``Servo``), around a pyramid mesh that translates and turns,
and beside a plane moving along a ``Table``: ``full`` runs STEPS steps, saving ``half.h5`` at
STEPS / 2; ``restart`` loads it and runs the second half. Rank 0 writes ``OUT_DIR/{mode}.npz``: the
positions, velocities, spins and wall histories by gid, the lid's servo state and the wall forces.
"""
import os
import sys

import numpy as np

import pardem

STEPS = 600
RD, RC, H = 2e-3, 0.02, 0.03        # grain radius, drum radius, lid height [m]


def system():
    g = np.arange(-4, 5)
    x, y, z = np.meshgrid(g, g, np.arange(3), indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1) * 2.05 * RD
    pts[:, 2] += RD + 1e-4
    b, h = 0.008, 0.006
    # inside the drum, clear of the pyramid (its box)
    keep = (np.hypot(pts[:, 0], pts[:, 1]) < RC - 1.2 * RD) & \
        ~((np.abs(pts[:, 0]) < b + RD) & (np.abs(pts[:, 1]) < b + RD) & (pts[:, 2] < h + RD))
    pts = pts[keep]
    rng = np.random.default_rng(3)
    pts[:, :2] += rng.uniform(-1e-5, 1e-5, (len(pts), 2))
    top = float(pts[:, 2].max()) + RD
    # the pyramid: four faces, apex up, in the bed
    base = np.array([[-b, -b, 0.0], [b, -b, 0.0], [b, b, 0.0], [-b, b, 0.0]])
    apex = np.array([0.0, 0.0, h])
    tris = np.array([[base[i], base[(i + 1) % 4], apex] for i in range(4)])
    law = pardem.wall_law("hertz", young=5e6, poisson=0.3, restitution=0.5, friction=0.4)
    lid = pardem.Servo(gain=0.5, force=0.05, max_speed=0.05, period=5)
    kinds = os.environ.get("WALL_KINDS", "planes,cylinder,mesh").split(",")
    normals = [[0, 0, 1], [0, 0, -1], [1, 0, 0]] if "planes" in kinds else [[0, 0, 1]]
    points = [[0, 0, 0], [0, 0, top - 1e-5], [-RC + 1e-3, 0, 0]] if "planes" in kinds else [[0, 0, 0]]
    motions = [pardem.Sinusoid((0, 0, 2e-4), 30.0), lid,
               pardem.MotionTable([0.0, 0.002, 0.004], [[0, 0, 0], [1e-3, 0, 0], [1e-3, 0, 0]])] \
        if "planes" in kinds else None
    walls = pardem.WallModel(
        normals=normals, points=points, law=law, motions=motions,
        cylinders=[pardem.Cylinder((0, 0, 0), (0, 0, 1), RC, inside=True, angular_velocity=3.0)]
        if "cylinder" in kinds else None,
        meshes=[pardem.Mesh(tris, motion=pardem.ConstantMotion((0.02, 0.0, 0.0)),
                            rotation=((0, 0, 0), (0, 0, 1), 5.0))] if "mesh" in kinds else None)
    contacts = pardem.ContactModel("hertz_mindlin", dict(young=5e6, poisson=0.3, friction=0.4,
                                                         restitution=0.5))
    return pardem.System(pardem.Particles(pts, RD, 2500.0, velocities=rng.uniform(-0.05, 0.05, (len(pts), 3))),
                         contacts=contacts, walls=walls,
                         integration=pardem.Integration(dt_fraction=0.3),
                         decomposition=pardem.Decomposition(slab_axis=0))


def dump(sim, path):
    p = sim.particles
    w = sim.plates
    lid = w.motions[1] if w.motions else pardem.Servo(1.0, force=0.0)
    rows = np.argsort(sim.elements.gid[:sim.elements.n_owned])
    hist = sim.comm.allgatherv(np.ascontiguousarray(sim.elements.wall_h[:sim.elements.n_owned][rows]
                                                    .reshape(len(rows), -1)))
    gids = sim.comm.allgatherv(np.sort(sim.elements.gid[:sim.elements.n_owned]).astype(np.int64))
    tri = w.triangle_forces(sim.comm)
    x, v, spin = p.positions, p.velocities, p.angular_velocities     # collectives
    if sim.comm.rank == 0:
        np.savez(path, x=x, v=v, w=spin,
                 hist=hist[np.argsort(gids)].astype(np.float64), lid=np.array([lid.speed, lid.offset_ref or 0.0, lid.time_ref or 0.0,
                                                           lid.measured]),
                 force=w.force, offsets=w.offsets, tri=tri, steps=sim.step_count)


def main(out, mode):
    comm = pardem.Communicator()
    if mode == "full":
        sim = pardem.build(comm, system())
        pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -9.81)))
        sim.run(STEPS // 2)
        pardem.save(sim, os.path.join(out, "half.h5"))
        sim.run(STEPS - STEPS // 2)
    else:
        sim = pardem.load(comm, os.path.join(out, "half.h5"))
        # the stored forces hold the weight already: add_fixes would apply it once more at once
        sim.fixes.append(pardem.Gravity((0.0, 0.0, -9.81)))
        sim.run(STEPS - STEPS // 2)
    dump(sim, os.path.join(out, f"{mode}.npz"))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
