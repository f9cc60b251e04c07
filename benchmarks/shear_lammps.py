"""Simple shear of the GRAN-SHEAR packing in pardem against LAMMPS' ``fix deform xy erate ... remap v``.

    python benchmarks/shear_lammps.py [--n 8000] [--lammps-log LOG] [--out benchmarks/results]

The packing (``../shared/peers/shear/packings/shear_N.npz``: positions, radii, peculiar velocities
and spins, the box) is sheared at the engineering rate ``gd = 4000 1/s`` (``dv_x/dy``) at
constant volume, dt = 2e-8 s, skin 2e-5 m, Hertz-Mindlin (E = 72 GPa, nu = 0.2, friction 0.5, no
damping), density 2500 kg/m^3, as the peers' LAMMPS run does (``run.sh lammps-simple N 1`` with
``EVERY=100``; its log holds the thermo lines compared here: step, contacts, Z, P, Pxx, Pyy, Pzz,
Pxy, with LAMMPS' sign, compression positive). pardem's cell is sheared through ``Cell.shear_rate``,
its velocities are the peculiar ones (LAMMPS' data file adds ``gd (y - yc)``). Both start from the
same doubles, so the trajectories agree for a few hundred steps and then only in their statistics
(the known contact-law differences, the peers' README). Prints, and writes as JSON and a figure,
the samples every 100 steps of the 200 + 2000 steps and the means over the timed samples with their
scatter (standard deviation of the samples). Rank 0 writes; any number of ranks.
"""
import argparse
import json
import os
import re
import sys

import numpy as np

import pardem
from pardem.engine.reducer import granular_measures

HERE = os.path.dirname(os.path.abspath(__file__))
PEERS = os.path.join(HERE, "..", "..", "shared", "peers", "shear")
GD, DT, SKIN = 4000.0, 2.0e-8, 2.0e-5


def lammps_samples(log):
    """{step: (contacts, Z, P, Pxy)} of the thermo lines of a ``run.sh lammps-simple`` log."""
    out = {}
    cols = None
    for line in open(log):
        t = line.split()
        if t[:2] == ["Step", "v_nc"]:
            cols = t
            continue
        if cols and len(t) == len(cols) and re.match(r"^\d+$", t[0]):
            row = dict(zip(cols, map(float, t)))
            out[int(row["Step"])] = (row["v_nc"], row["v_Z"], row["v_P"], row["v_Pxy"])
        elif cols and t and not re.match(r"^\d", t[0]):
            cols = None
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=8000)
    p.add_argument("--lammps-log", default=None)
    p.add_argument("--out", default=os.path.join(HERE, "results"))
    p.add_argument("--warm", type=int, default=200)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--every", type=int, default=100)
    a = p.parse_args()
    comm = pardem.Communicator()
    z = np.load(os.path.join(PEERS, "packings", f"shear_{a.n}.npz"))
    x, r = np.asarray(z["pos"], float), np.asarray(z["radius"], float)
    v, w = np.asarray(z["v"], float), np.asarray(z["w"], float)
    lo, hi = np.asarray(z["lo"], float), np.asarray(z["hi"], float)
    system = pardem.System(
        pardem.Particles(x, r, 2500.0, velocities=v, angular_velocities=w),
        contacts=pardem.ContactModel("hertz_mindlin", {"young": 72e9, "poisson": 0.2, "friction": 0.5}),
        cell=pardem.Cell(lo, hi - lo, (True, True, True), shear_rate=(GD, 0.0, 0.0)),
        integration=pardem.Integration(dt=DT, orientation=False),
        decomposition=pardem.Decomposition(skin=SKIN))
    sim = pardem.build(comm, system)
    rows = {}
    done = 0
    total = a.warm + a.steps
    while done < total:
        k = a.every if done else min(a.every, a.warm) or a.every
        sim.run(k)
        done += k
        m = granular_measures(sim)
        s = -np.asarray(m["stress"])      # compression positive, as LAMMPS
        rows[done] = (float(m["n_contacts"]), float(m["Z"]), float(np.trace(s) / 3.0), float(s[0, 1]))
        if comm.rank == 0:
            print(f"pardem step {done}: contacts {rows[done][0]:.0f} Z {rows[done][1]:.4f} "
                  f"P {rows[done][2]:.5g} Pa Pxy {rows[done][3]:.5g} Pa flips {sim.cell.flips}", flush=True)
    if comm.rank != 0:
        return
    log = a.lammps_log or os.path.join(os.environ.get("SHEAR_WORK", "/tmp/pardem-shear"),
                                       f"lammps-simple_N{a.n}_r1", "log.lammps-simple")
    lmp = lammps_samples(log)
    steps = sorted(s for s in rows if s in lmp and s > a.warm)
    if not steps:
        sys.exit(f"no LAMMPS thermo line at pardem's sample steps in {log} (run.sh with EVERY={a.every})")
    names = ("contacts", "Z", "P", "Pxy")
    summary = {"n": a.n, "gd": GD, "dt": DT, "steps": steps, "strain_end": GD * DT * max(steps)}
    for c, name in enumerate(names):
        pd_ = np.array([rows[s][c] for s in steps])
        lm = np.array([lmp[s][c] for s in steps])
        summary[name] = {"pardem": pd_.tolist(), "lammps": lm.tolist(),
                         "pardem_mean": float(pd_.mean()), "lammps_mean": float(lm.mean()),
                         "scatter": float(np.std(np.concatenate([pd_ - pd_.mean(), lm - lm.mean()]))),
                         "relative_difference_of_means": float(pd_.mean() / lm.mean() - 1.0)}
        d = summary[name]
        print(f"{name:8s} pardem {d['pardem_mean']:.6g}  LAMMPS {d['lammps_mean']:.6g}  "
              f"pardem/LAMMPS - 1 = {d['relative_difference_of_means']:+.2%}  scatter {d['scatter']:.3g}  "
              f"|difference| / scatter = {abs(d['pardem_mean'] - d['lammps_mean']) / d['scatter']:.2f}")
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, f"shear_lammps_N{a.n}.json"), "w") as f:
        json.dump(summary, f, indent=1)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    gam = GD * DT * np.array(steps)
    ax[0].plot(gam, summary["Z"]["pardem"], "o-", label="pardem")
    ax[0].plot(gam, summary["Z"]["lammps"], "s--", label="LAMMPS")
    ax[0].set(xlabel="shear strain gamma (from the packing)", ylabel="Z = 2 contacts / N",
              title=f"N = {a.n}, simple shear gd = {GD:g} 1/s")
    ax[1].plot(gam, -np.array(summary["Pxy"]["pardem"]) / 1e6, "o-", label="pardem")
    ax[1].plot(gam, -np.array(summary["Pxy"]["lammps"]) / 1e6, "s--", label="LAMMPS")
    ax[1].set(xlabel="shear strain gamma", ylabel="shear stress sigma_xy [MPa] (= -Pxy)")
    for x_ in ax:
        x_.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, f"shear_lammps_N{a.n}.png"), dpi=110)


if __name__ == "__main__":
    main()
