"""The GRAN-SHEAR benchmark case (``../shared/peers/CASES.md``), shared by the benchmarks.

A dense random packing of polydisperse spheres (radii uniform in [0.08, 0.12] mm) at solid fraction
0.61 in a fully periodic cube, stored in a random row order, sheared at constant volume: pure shear,
x stretching at +2000 1/s, y shortening at -2000 1/s, z fixed. The GRAN material (2500 kg/m^3,
E = 72 GPa, Poisson 0.2, friction 0.5, Hertz-Mindlin with history, no damping, no gravity);
dt = 2e-8 s, skin 2e-5 m, lists checked every step; 200 warm-up steps then 2000 timed steps.

The initial states are the shared packings ``shear_N.npz`` (positions and radii float64, peculiar
velocities and spins float32, the box), in ``PARDEM_SHEAR_PACKINGS`` or
``../shared/peers/shear/packings`` beside the project.
"""
import math
import os

import numpy as np

DENSITY, YOUNG, POISSON, FRICTION = 2500.0, 72e9, 0.2, 0.5
PARAMS = {"young": YOUNG, "poisson": POISSON, "friction": FRICTION}
RATE = 2000.0
DT, SKIN = 2e-8, 2e-5
HERE = os.path.dirname(os.path.abspath(__file__))


def packing_path(n):
    """Path of the packing of ``n`` spheres."""
    folder = os.environ.get("PARDEM_SHEAR_PACKINGS") or os.path.normpath(
        os.path.join(HERE, "..", "..", "shared", "peers", "shear", "packings"))
    if not os.path.isdir(folder):
        folder = "/work/shared/peers/shear/packings"
    return os.path.join(folder, f"shear_{n}.npz")


def load(n):
    """``{pos [n, 3], radius [n], v [n, 3], w [n, 3], lo [3], hi [3]}`` (float64) of the packing;
    checks its stored dt, skin and rate against this case's."""
    with np.load(packing_path(n)) as d:
        st = {k: np.asarray(d[k], dtype=np.float64) for k in ("pos", "radius", "v", "w", "lo", "hi")}
        meta = {k: float(d["meta_" + k]) for k in ("rate", "dt", "skin")}
    if len(st["pos"]) != n:
        raise ValueError(f"{packing_path(n)} holds {len(st['pos'])} spheres, not {n}")
    if (meta["rate"], meta["dt"], meta["skin"]) != (RATE, DT, SKIN):
        raise ValueError(f"{packing_path(n)}: rate, dt, skin {meta} differ from the case's")
    return st


def system(st, slab_axis=0, orientation=False):
    """The pardem ``System`` of a loaded packing ``st`` (peculiar velocities: the cell's affine
    motion is added by the contact law)."""
    from pardem.engine.system import Cell, ContactModel, Decomposition, Integration, Particles, System
    return System(Particles(st["pos"], st["radius"], DENSITY, velocities=st["v"], angular_velocities=st["w"]),
                  contacts=ContactModel("hertz_mindlin", PARAMS),
                  cell=Cell(st["lo"], st["hi"] - st["lo"], rate=(RATE, -RATE, 0.0)),
                  integration=Integration(dt=DT, orientation=orientation),
                  decomposition=Decomposition(slab_axis=slab_axis, skin=SKIN))


def lammps_trates(rate=RATE, dt=DT):
    """``fix deform ... trate`` of x and y [1/s] that give pardem's edges ``L0 (1 +- g dt)^n`` at
    every step n: ``ln(1 +- g dt) / dt``."""
    return math.log1p(rate * dt) / dt, math.log1p(-rate * dt) / dt


def lammps_data(st, path):
    """Write ``st`` as a LAMMPS ``atom_style sphere`` data file (17 digits, so both codes start
    from the same doubles), with lab-frame velocities: the peculiar ones plus the streaming
    velocity of LAMMPS' deforming box, ``(tx (x - xc), ty (y - yc), 0)`` about the fixed centre."""
    pos, lo, hi = st["pos"], st["lo"], st["hi"]
    tx, ty = lammps_trates()
    c = 0.5 * (lo + hi)
    v = st["v"].copy()
    v[:, 0] += tx * (pos[:, 0] - c[0])
    v[:, 1] += ty * (pos[:, 1] - c[1])
    with open(path, "w") as fh:
        fh.write(f"GRAN-SHEAR N={len(pos)}\n\n{len(pos)} atoms\n1 atom types\n\n")
        for a, axis in enumerate("xyz"):
            fh.write(f"{lo[a]:.17g} {hi[a]:.17g} {axis}lo {axis}hi\n")
        fh.write("\nAtoms # sphere\n\n")
        fh.writelines(f"{k + 1} 1 {2 * r:.17g} {DENSITY:.17g} {x:.17g} {y:.17g} {z:.17g}\n"
                      for k, (r, (x, y, z)) in enumerate(zip(st["radius"], pos)))
        fh.write("\nVelocities\n\n")
        fh.writelines(f"{k + 1} {a:.17g} {b:.17g} {c_:.17g} {p:.17g} {q:.17g} {s:.17g}\n"
                      for k, ((a, b, c_), (p, q, s)) in enumerate(zip(v, st["w"])))
    return tx, ty
