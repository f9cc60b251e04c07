"""Pressure scaling of the elastic moduli of a Hertz-Mindlin packing, computed two ways.

A bidisperse glass packing (``drivers/isotropic_small.toml``) is prepared by the isotropic
protocol at increasing pressures p0 (each continuing the previous packing, FIRE preparation).
At each pressure the bulk and shear moduli are

* measured by the protocol (``isotropic.moduli``: one-step affine strain, then dynamic
  relaxation), and
* computed from the static linear response of the contact network
  (``pardem.protocols.moduli_check``: stiffness matrix, sparse solve; ``tangent`` = zero strain,
  ``protocol`` = the protocol's secant at its strain to second order), with Walton's EMT and
  the affine sums over the contacts beside them.

Then the log-log slopes d ln K / d ln p and d ln mu / d ln p between successive pressures are
printed. Hertz contacts with a fixed network give 1/3 (EMT); a real packing gains contacts with
pressure (Z rises from the isostatic 6), so the relaxed moduli, in particular mu (which vanishes
at jamming as (Z - 6)), scale faster than p^(1/3) at low pressure.

Run:  python examples/granular_moduli_scaling.py [--n 200] [--pressures 1e5,1e6,1e7] [--friction 0.3]
      python examples/granular_moduli_scaling.py --checkpoint DIR/checkpoints/checkpoint-N.h5 [--strain E]
      (the static moduli of one isotropic checkpoint, as JSON; mpiexec -n 2 works too)
"""
import argparse
import json
import os
import time

import numpy as np

from pardem.config import load_deck
from pardem.parallel.communicator import Communicator
from pardem.protocols import isotropic as iso
from pardem.protocols import moduli_check

DECK = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "drivers", "isotropic_small.toml")
KEYS = ("K_relaxed", "mu_relaxed", "K_affine", "mu_affine")


def study(n, pressures, friction, seed=1, comm=None):
    """Rows (one per pressure) of the dynamic and static moduli [Pa]."""
    comm = Communicator() if comm is None else comm
    deck = load_deck(iso.SCHEMA, DECK,
                     [f"sample.n={n}", f"sample.seed={seed}", 'preparation.relaxation="fire"',
                      f"material.friction={friction}"])
    case, rows = None, []
    for p0 in sorted(pressures):
        t0 = time.perf_counter()
        case, info = iso.prepare(comm, deck, p0, case)
        sim = case.sim
        sim.elements.v[:] = 0.0
        sim.elements.w[:] = 0.0
        net = iso.network(sim)
        e = 0.01 * net["mean_overlap_ratio"]
        static = moduli_check.static_moduli(sim, deck["material"], e)
        dyn = iso.moduli(sim, deck, e)
        rows.append({"p0": p0, "p": net["p"], "Z": net["Z"], "Z_no_rattlers": net["Z_no_rattlers"],
                     "converged": info["converged"], "strain": e,
                     "dynamic": {k: dyn[k] for k in KEYS},
                     "static_tangent": {k: static["tangent"][k] for k in KEYS},
                     "static_protocol": {k: static["protocol"][k] for k in KEYS},
                     "iso_average": {k: static["tangent"][k] for k in ("K_iso_relaxed", "mu_iso_relaxed",
                                                                      "K_iso_affine", "mu_iso_affine")},
                     "emt": static["emt"], "seconds": time.perf_counter() - t0})
    return rows


def slopes(rows, group, key):
    p = np.array([r["p"] for r in rows])
    v = np.array([r[group][key] for r in rows])
    return (np.diff(np.log(v)) / np.diff(np.log(p))).tolist()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--pressures", default="1e5,1e6,1e7")
    ap.add_argument("--friction", type=float, default=0.3)
    ap.add_argument("--json", action="store_true", help="print the rows as JSON too")
    ap.add_argument("--checkpoint", help="only the static moduli of this isotropic checkpoint (JSON)")
    ap.add_argument("--strain", type=float, default=None, help="with --checkpoint: the protocol's strain e")
    a = ap.parse_args()
    if a.checkpoint:
        comm = Communicator()
        out = moduli_check.from_checkpoint(comm, a.checkpoint, None, a.strain)   # the checkpoint's grains
        if comm.is_root:
            print(json.dumps(out, indent=1))
        return
    rows = study(a.n, [float(x) for x in a.pressures.split(",")], a.friction)
    print(f"{'p [Pa]':>10} {'Z':>6} {'Z_nr':>6} | {'K dyn':>10} {'K static':>10} {'rel':>9} | "
          f"{'mu dyn':>10} {'mu static':>10} {'rel':>9} | "
          f"{'K_aff':>10} {'K_EMT':>10} {'mu_aff':>10} {'mu_EMT':>10}")
    for r in rows:
        d, s = r["dynamic"], r["static_protocol"]
        print(f"{r['p']:10.4g} {r['Z']:6.3f} {r['Z_no_rattlers']:6.3f} | {d['K_relaxed']:10.5g} {s['K_relaxed']:10.5g} "
              f"{s['K_relaxed'] / d['K_relaxed'] - 1:9.2e} | {d['mu_relaxed']:10.5g} {s['mu_relaxed']:10.5g} "
              f"{s['mu_relaxed'] / d['mu_relaxed'] - 1:9.2e} | {s['K_affine']:10.5g} {r['emt']['K_EMT']:10.5g} "
              f"{s['mu_affine']:10.5g} {r['emt']['mu_EMT']:10.5g}")
    print("log-log slopes between successive pressures (Hertz, fixed network: 1/3):")
    for group, key in (("dynamic", "K_relaxed"), ("static_tangent", "K_relaxed"), ("dynamic", "mu_relaxed"),
                       ("static_tangent", "mu_relaxed"), ("static_tangent", "K_affine"),
                       ("static_tangent", "mu_affine"), ("emt", "K_EMT")):
        print(f"  {group:15s} {key:11s} " + "  ".join(f"{x:.4f}" for x in slopes(rows, group, key)))
    if a.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
