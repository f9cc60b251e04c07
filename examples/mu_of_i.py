"""mu(I) rheology: steady simple shear at constant normal stress over two decades of inertial number.

A periodic sample of Hertz-Mindlin spheres (friction 0.5, restitution 0.5, radii uniform in
[0.8, 1.2] mm, density 2500 kg/m^3, Young's modulus 70 MPa, seeded) is sheared at ``dv_x/dy = gd``
(``Cell.shear_rate``, Lees-Edwards through the tilted cell) while a servo holds the normal stress
``-sigma_yy`` at ``P0 = 100 kPa`` (``normal`` servo on y, gain ``2 gd / P0`` and rate cap ``2 gd``:
the cell's y edge relaxes over a few percent of shear strain at every rate). The shear rate steps
down through the inertial numbers ``I = gd d / sqrt(P0 / rho)`` of ``I_LEVELS`` (d the mean
diameter), from the highest (which first compacts the initial gas, solid fraction 0.3) to the
lowest, as a rate-stepping rheometer does. At each level the first ``TRANSIENT`` of shear strain is
dropped (the dilatancy and the contact network relax to the new rate) and the stresses are
averaged over the next ``WINDOW``: ``tau = <sigma_xy>``, ``P = <-sigma_yy>`` (the Love-Weber stress of
the contacts, ``Simulation.global_stress``, plus the kinetic stress ``-sum m v v / V`` of the
fluctuating velocities), ``mu = tau / P``, its standard error from 5 block means, and ``I`` from the
measured ``P``. The stiffness number ``P0 / E = 1.4e-3`` keeps the mean overlap near 1 % of a
diameter (Hertz: ``(P0 / E)^(2/3)``), so the flows are in the inertial regime, not the soft one
(Chialvo, Sun and Sundaresan, Phys. Rev. E 85, 021305 (2012)).

The points are fitted (weighted least squares, ``scipy.optimize.curve_fit``, the standard errors as
absolute weights) to the form of Jop, Forterre and Pouliquen, Nature 441, 727 (2006) (GDR MiDi,
Eur. Phys. J. E 14, 341 (2004) for the inertial number):

    mu(I) = mu_s + (mu_2 - mu_s) / (I0 / I + 1)

When the points do not bound the saturation (the weighted fit runs ``mu_2`` or ``I0`` to a bound of
its box, or their errors exceed them: with I <= 0.3 the data hardly reach the curve's bend at
``I ~ I0``), the script says so and fits ``mu_s, mu_2`` again with ``I0`` fixed at Jop et al.'s 0.279.
It writes ``mu_of_i.csv`` (units in the header) and ``mu_of_i.png`` (mu against I, log I axis, the
points with their error bars, the fits and the experimental curve of Jop et al. for glass beads)
into ``--out``. The full run has 1000 grains: 1 strain unit at the first level (from the gas),
then 0.3 + 2 strain units per level; the level I = 1e-3 alone takes about 1.4e5 steps.

Checks (exit status 1 if one fails):

(a) mu increases with I: ``mu(I_max) - mu(I_min) > 3 s`` (s the combined standard error; 2 s with
    ``--quick``, whose two short windows of a few hundred grains leave s near a third of the rise:
    a one-sided 2 s bound fails a true rise of 3 s about one time in six, a flat mu(I) in 49 of 50),
    and no level lies below the one before it by more than 3 of their combined standard errors.
(b) (not with ``--quick``) the quasi-static friction ``mu_s`` of the fit lies in ``MU_S_RANGE``
    = [0.33, 0.43], with a fit uncertainty below 0.03 (so the range is what decides). Reference
    values: Jop et al. (2006) measured ``mu_s = tan 20.9 deg = 0.38``, ``mu_2 = tan 32.76 deg =
    0.64``, ``I0 = 0.279`` for glass beads; 3D simple-shear DEM of spheres with contact friction
    0.5 gives a quasi-static friction of about 0.37 (Chialvo et al. 2012, their fig. 4; the value
    ``examples/simple_shear.py`` compares with). The range is 0.38 +- 0.05: the spread of these
    reference values (0.37-0.38) widened by the scatter of quasi-static friction between 3D DEM
    studies that differ in contact law, polydispersity and stiffness (a few hundredths) and by the
    finite-size scatter of a few hundred grains. It excludes frictionless spheres (mu_s ~ 0.1) and
    2D disks at this friction. (da Cruz et al., Phys. Rev. E 72, 021309 (2005) is the 2D
    plane-shear study that set the inertial-number description; its disk values are not a 3D
    reference.)

``--quick`` (the test suite): 300 grains, two levels, I = 0.3 and 0.01, shorter windows; only (a)
(the fit needs more points than parameters).

Run:  python examples/mu_of_i.py [--quick] [--out DIR]
      (or: mpiexec -n 2 python examples/mu_of_i.py ...)
"""
import argparse
import os
import sys

import numpy as np
from scipy import optimize

import pardem
from simple_shear import gas          # non-overlapping periodic gas (random sequential addition)

I_LEVELS = (0.3, 0.1, 0.03, 0.01, 0.003, 0.001)     # inertial numbers, highest first
MU_S_RANGE = (0.33, 0.43)                           # module docstring, check (b)
MU_S_REF = 0.38                                     # Jop et al. 2006; Chialvo et al. 2012: 0.37
JOP = (0.38, 0.64, 0.279)                           # mu_s, mu_2, I0 of Jop et al. 2006 (glass beads)
SAMPLE = 0.02                                       # shear strain between two stress samples
BLOCKS = 5                                          # blocks of the standard error


def mu_of_i(i, mu_s, mu_2, i0):
    """The Jop-Forterre-Pouliquen law: mu at inertial number ``i``."""
    return mu_s + (mu_2 - mu_s) / (i0 / i + 1.0)


def fit_law(i, mu, err, i0=None):
    """Weighted least squares of ``mu_of_i`` (all three parameters, or ``mu_s, mu_2`` at a fixed
    ``i0``): ``(params [3], errors [3], chi2, constrained)``; the errors are the covariance's,
    scaled by ``sqrt(chi2 / dof)`` when that exceeds 1 (the block errors then underestimate the
    scatter); ``constrained`` is False when a parameter ends at a bound or its error exceeds it."""
    lo, hi = [0.0, 0.0, 1e-4], [2.0, 5.0, 100.0]
    if i0 is None:
        f, guess = mu_of_i, JOP
    else:
        f, guess, lo, hi = (lambda x, a, b: mu_of_i(x, a, b, i0)), JOP[:2], lo[:2], hi[:2]
    popt, pcov = optimize.curve_fit(f, i, mu, p0=guess, sigma=err, absolute_sigma=True, bounds=(lo, hi))
    chi2 = float(np.sum(((mu - f(i, *popt)) / err) ** 2))
    dof = len(mu) - len(popt)
    perr = np.sqrt(np.diag(pcov)) * np.sqrt(max(1.0, chi2 / dof))
    at_bound = np.any(np.isclose(popt, lo, rtol=1e-3, atol=0.0) | np.isclose(popt, hi, rtol=1e-3, atol=0.0))
    constrained = bool(not at_bound and np.all(perr < np.abs(popt)))
    if i0 is not None:
        popt, perr = np.append(popt, i0), np.append(perr, 0.0)
    return popt, perr, chi2, constrained


def stress(sim, volume):
    """The total stress [3, 3] [Pa], tension positive: the contacts' Love-Weber stress plus the
    kinetic stress of the fluctuating velocities (collective)."""
    v = sim.particles.velocities
    m = sim.particles.masses
    return sim.global_stress() - (v * m[:, None]).T @ v / volume


def level(sim, gd, p0, transient, window, volume_solid, n):
    """Shear at ``gd`` [1/s] over ``transient + window`` strain; the window's sample rows
    ``(strain, tau [Pa], P [Pa], phi, Z)`` [k, 5] (collective)."""
    sim.cell.shear_rate[0] = gd
    sim.cell.servo["gain"] = 2.0 * gd / p0
    sim.cell.servo["max_rate"] = 2.0 * gd
    steps = max(1, int(round(SAMPLE / (gd * sim.dt))))
    start = sim.cell.shear_strain[0]
    rows = []
    while sim.cell.shear_strain[0] - start < transient + window - 1e-9:
        sim.run(steps)
        s = stress(sim, sim.cell.volume)
        if sim.cell.shear_strain[0] - start > transient:
            touching = sim.comm.sum(float(sim.contacts.n_touching))
            rows.append((sim.cell.shear_strain[0], s[0, 1], -s[1, 1], volume_solid / sim.cell.volume,
                         2.0 * touching / n))
    return np.array(rows)


def block_error(a, b, blocks=BLOCKS):
    """The standard error of ``mean(a) / mean(b)`` from ``blocks`` consecutive block ratios."""
    k = len(a) // blocks
    if k == 0:
        return np.nan
    ratios = [np.mean(a[j * k:(j + 1) * k]) / np.mean(b[j * k:(j + 1) * k]) for j in range(blocks)]
    return float(np.std(ratios, ddof=1) / np.sqrt(blocks))


def write(out, table, fit, fixed, quick):
    """``mu_of_i.csv`` and ``mu_of_i.png`` into ``out`` (rank 0)."""
    os.makedirs(out, exist_ok=True)
    header = ("I_target [-], I [-], gamma_dot [1/s], tau [Pa], P [Pa], mu [-], mu_stderr [-], "
              "phi [-], Z [-], samples [-]")
    np.savetxt(os.path.join(out, "mu_of_i.csv"), table, delimiter=",", header=header, fmt="%.10g")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed, so no figure", file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(6.0, 4.2))
    ax.errorbar(table[:, 1], table[:, 5], yerr=table[:, 6], fmt="o", color="C0", capsize=3,
                label="pardem, friction 0.5 (steady simple shear)")
    grid = np.logspace(np.log10(table[:, 1].min()) - 0.3, np.log10(table[:, 1].max()) + 0.3, 200)
    if fit is not None:
        (ms, m2, i0), err, _, free = fit
        ax.plot(grid, mu_of_i(grid, ms, m2, i0), "-", color="C0",
                label=f"fit: $\\mu_s$={ms:.3f}$\\pm${err[0]:.3f}, $\\mu_2$={m2:.3g}$\\pm${err[1]:.2g}, "
                      f"$I_0$={i0:.3g}$\\pm${err[2]:.2g}" + ("" if free else " (not constrained)"))
    if fixed is not None:
        (ms, m2, i0), err, _, _ = fixed
        ax.plot(grid, mu_of_i(grid, ms, m2, i0), ":", color="C1",
                label=f"fit at $I_0$={i0}: $\\mu_s$={ms:.3f}$\\pm${err[0]:.3f}, $\\mu_2$={m2:.3f}$\\pm${err[1]:.3f}")
    ax.plot(grid, mu_of_i(grid, *JOP), "--", color="0.4",
            label="Jop et al. 2006, glass beads ($\\mu_s$=0.38, $\\mu_2$=0.64, $I_0$=0.279)")
    ax.set_xscale("log")
    ax.set_xlabel(r"inertial number $I = \dot\gamma\, d / \sqrt{P/\rho}$ [-]")
    ax.set_ylabel(r"friction coefficient $\mu = \tau / P$ [-]")
    ax.set_title("mu(I) of frictional spheres" + (" (--quick: shortened run)" if quick else ""))
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "mu_of_i.png"), dpi=120)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="300 grains, I = 0.3 and 0.01 (the test suite)")
    ap.add_argument("--out", default="mu_of_i-output", help="folder of the CSV and the figure")
    ap.add_argument("--seed", type=int, default=2026)
    a = ap.parse_args(argv)
    if a.quick:
        n, levels, transient, window, first = 300, (0.3, 0.01), 0.3, 0.7, 1.0
    else:
        n, levels, transient, window, first = 1000, I_LEVELS, 0.3, 2.0, 1.0
    p0, rho = 1e5, 2500.0                               # [Pa], [kg/m^3]
    rng = np.random.default_rng(a.seed)
    x, r, side = gas(n, 0.3, rng)
    d = 2.0 * float(r.mean())
    volume_solid = float(np.sum(4.0 / 3.0 * np.pi * r ** 3))
    comm = pardem.Communicator()
    gd0 = levels[0] * np.sqrt(p0 / rho) / d
    servo = {"kind": "normal", "axis": 1, "pressure": p0, "gain": 2.0 * gd0 / p0, "max_rate": 2.0 * gd0}
    system = pardem.System(
        pardem.Particles(x, r, rho),
        contacts=pardem.ContactModel("hertz_mindlin", {"young": 7e7, "poisson": 0.3, "friction": 0.5,
                                                       "restitution": 0.5}),
        cell=pardem.Cell((0.0, 0.0, 0.0), (side,) * 3, (True, True, True), shear_rate=(gd0, 0.0, 0.0),
                         servo=servo),
        integration=pardem.Integration(dt_fraction=0.2, orientation=False),
        decomposition=pardem.Decomposition(skin=0.1 * d))
    sim = pardem.build(comm, system)
    root = comm.rank == 0
    if root:
        print(f"mu_of_i: {n} grains, {comm.size} rank(s), dt {sim.dt:.4g} s, P0 {p0:g} Pa, d {d:.4g} m")
        print("  I_target        I   gd [1/s]       tau [Pa]         P [Pa]        mu    stderr     phi      Z  samples")
    table = []
    for k, target in enumerate(levels):
        gd = target * np.sqrt(p0 / rho) / d
        rows = level(sim, gd, p0, first if k == 0 else transient, window, volume_solid, n)
        tau, p = float(np.mean(rows[:, 1])), float(np.mean(rows[:, 2]))
        mu, err = tau / p, block_error(rows[:, 1], rows[:, 2])
        inertial = gd * d / np.sqrt(p / rho)
        table.append((target, inertial, gd, tau, p, mu, err, np.mean(rows[:, 3]), np.mean(rows[:, 4]), len(rows)))
        if root:
            print(f"  {target:8.3g} {inertial:8.4g} {gd:10.4g} {tau:14.8g} {p:14.8g} {mu:9.6f} {err:9.2e} "
                  f"{table[-1][7]:7.4f} {table[-1][8]:6.3f} {len(rows):8d}")
    table = np.array(table)
    order = np.argsort(table[:, 1])
    table = table[order]
    mu, err = table[:, 5], table[:, 6]

    # (a) mu increases with I
    rise = mu[-1] - mu[0]
    rise_err = float(np.hypot(err[-1], err[0]))
    drops = [(mu[j] - mu[j + 1]) / np.hypot(err[j], err[j + 1]) for j in range(len(mu) - 1)]
    ok_rise = rise > (2.0 if a.quick else 3.0) * rise_err and max(drops) < 3.0

    # (b) the fit and mu_s against the literature
    fit, fixed, ok_fit = None, None, True
    if len(table) > 3:
        fit = fit_law(table[:, 1], mu, err)
        ok_fit = MU_S_RANGE[0] <= fit[0][0] <= MU_S_RANGE[1] and fit[1][0] < 0.03
        if not fit[3]:
            fixed = fit_law(table[:, 1], mu, err, i0=JOP[2])
    if root:
        print(f"mu rises by {rise:.4f} +- {rise_err:.4f} from I = {table[0, 1]:.4g} to I = {table[-1, 1]:.4g} "
              f"(largest drop between neighbours {max(drops):.2f} standard errors)")
        if fit is not None:
            (ms, m2, i0), (es, e2, ei), chi2, free = fit
            print(f"fit mu(I) = mu_s + (mu_2 - mu_s) / (I0 / I + 1): mu_s = {ms:.4f} +- {es:.4f}, "
                  f"mu_2 = {m2:.4f} +- {e2:.4f}, I0 = {i0:.4f} +- {ei:.4f} (chi2 {chi2:.2f}, "
                  f"{len(mu) - 3} degrees of freedom; errors scaled by sqrt(chi2 / dof) when above 1)")
            if not free:
                (fs, f2, _), (fes, fe2, _), fchi2, _ = fixed
                print(f"mu_2 and I0 are not separately constrained by I <= {table[-1, 1]:.2g} (the fit runs to "
                      f"a bound or their error exceeds them); with I0 fixed at {JOP[2]} (Jop et al.): "
                      f"mu_s = {fs:.4f} +- {fes:.4f}, mu_2 = {f2:.4f} +- {fe2:.4f} (chi2 {fchi2:.2f})")
            print(f"mu_s against the literature ({MU_S_REF} for contact friction 0.5): range "
                  f"{MU_S_RANGE[0]}-{MU_S_RANGE[1]}")
        write(a.out, table, fit, fixed, a.quick)
        print(f"wrote {os.path.join(a.out, 'mu_of_i.csv')} and mu_of_i.png")
        print("PASS" if ok_rise and ok_fit else "FAIL")
    return 0 if ok_rise and ok_fit else 1


if __name__ == "__main__":
    sys.exit(main())
