"""Simple shear: a periodic sample sheared at constant normal stress reaches a steady friction.

A few hundred Hertz-Mindlin spheres (friction 0.5, restitution 0.5, radii uniform in [0.8, 1.2] mm,
seeded) start as a loose gas (solid fraction 0.3, non-overlapping centres) in a fully periodic
cell that shears at ``dv_x/dy = gd`` (``Cell.shear_rate``: the cell tilts, an image across y moves
along x with it, Lees-Edwards; the tilt flips at half the edge). A servo holds the normal stress
``sigma_yy`` at ``-p0`` (``normal`` servo on y: the cell's y edge shrinks or grows); x and z keep
their edges. The gas compacts under the normal stress while it shears, then flows in a steady
state. Every ``CHUNK`` of strain the script prints the shear strain, the shear stress
``sigma_xy``, the normal stress, the solid fraction and the coordination.

Check: the steady friction ``mu = sigma_xy / -sigma_yy`` (the mean over the second half of the
strain) of dense flow at a small inertial number ``I = gd d / sqrt(p0 / rho)`` lies in the
published range for a grain friction of 0.5: 3D periodic simple-shear DEM gives ``mu ~ 0.36-0.40``
in the quasi-static limit rising with I (``mu(I) = mu_s + (mu_2 - mu_s) / (I_0 / I + 1)``;
Chialvo, Sun and Sundaresan, Phys. Rev. E 85, 021305 (2012), fig. 4, mu_p = 0.5:
mu_s ~ 0.37; da Cruz et al., Phys. Rev. E 72, 021309 (2005) for the form). With the sample's few
hundred grains and the scatter of a short run (a few strain units), the bounds are 0.25 and 0.55:
frictionless grains give ~0.1 and a sample not sheared through its cell (no Lees-Edwards motion
across the y faces) no steady stress at all, both outside them.

Run:  python examples/simple_shear.py [--quick]    (or: mpiexec -n 2 python examples/simple_shear.py --quick)
Exit status 1 if the check fails.
"""
import argparse
import sys

import numpy as np

import pardem

MU_RANGE = (0.25, 0.55)      # module docstring
CHUNK = 0.1                  # strain between two printed lines


def gas(n, phi, rng):
    """``n`` non-overlapping spheres (random sequential addition): centres [n, 3] [m], radii [n]
    [m], cube edge [m] for solid fraction ``phi``."""
    r = rng.uniform(0.8e-3, 1.2e-3, n)
    side = (float(np.sum(4.0 / 3.0 * np.pi * r ** 3)) / phi) ** (1.0 / 3.0)
    x = np.empty((n, 3))
    for k in range(n):
        while True:
            p = rng.uniform(0.0, side, 3)
            d = x[:k] - p
            d -= side * np.round(d / side)
            if k == 0 or np.min(np.einsum("ij,ij->i", d, d) - (r[:k] + r[k]) ** 2) > 0.0:
                x[k] = p
                break
    return x, r, side


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer grains and less strain (the test suite)")
    a = ap.parse_args()
    n, strain = (300, 1.6) if a.quick else (1000, 4.0)
    p0, rho, gd = 1e5, 2500.0, 30.0          # [Pa], [kg/m^3], [1/s]
    rng = np.random.default_rng(2026)
    x, r, side = gas(n, 0.3, rng)
    d = 2.0 * float(r.mean())
    inertial = gd * d / np.sqrt(p0 / rho)
    comm = pardem.Communicator()
    servo = {"kind": "normal", "axis": 1, "pressure": p0, "gain": 50.0 / p0, "max_rate": 50.0}
    system = pardem.System(
        pardem.Particles(x, r, rho),
        contacts=pardem.ContactModel("hertz_mindlin", {"young": 7e7, "poisson": 0.3, "friction": 0.5,
                                                       "restitution": 0.5}),
        cell=pardem.Cell((0.0, 0.0, 0.0), (side,) * 3, (True, True, True), shear_rate=(gd, 0.0, 0.0),
                         servo=servo),
        integration=pardem.Integration(dt_fraction=0.2, orientation=False),
        decomposition=pardem.Decomposition(skin=0.1 * d))
    sim = pardem.build(comm, system)
    steps = max(1, int(round(CHUNK / (gd * sim.dt))))
    root = comm.rank == 0
    if root:
        print(f"{n} grains, {comm.size} rank(s), dt {sim.dt:.3g} s, inertial number I = {inertial:.3g}")
        print("  strain   sigma_xy [Pa]  -sigma_yy [Pa]   mu      phi     Z")
    rows = []
    done = 0.0
    while done < strain - 1e-9:
        sim.run(steps)
        done = sim.cell.shear_strain[0]
        s = sim.global_stress()
        c = sim.contacts
        touching = comm.sum(float(c.n_touching))
        phi = float(np.sum(4.0 / 3.0 * np.pi * r ** 3)) / sim.cell.volume
        mu = s[0, 1] / -s[1, 1]
        rows.append((done, s[0, 1], -s[1, 1], mu))
        if root:
            print(f"  {done:6.3f}  {s[0, 1]:12.5g}  {-s[1, 1]:12.5g}  {mu:7.4f}  {phi:6.4f}  {2 * touching / n:5.3f}")
    rows = np.array(rows)
    steady = rows[rows[:, 0] > 0.5 * strain]
    mu_mean = float(np.mean(steady[:, 1]) / np.mean(steady[:, 2]))
    ok = MU_RANGE[0] <= mu_mean <= MU_RANGE[1]
    if root:
        print(f"steady friction mu {mu_mean:.4f} (mean over strain > {0.5 * strain:g}; published range "
              f"{MU_RANGE[0]}-{MU_RANGE[1]}), normal stress {np.mean(steady[:, 2]):.5g} Pa (target {p0:g}), "
              f"tilt flips {sim.cell.flips}")
        print("PASS" if ok else "FAIL")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
