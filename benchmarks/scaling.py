"""Strong and weak scaling of the slab decomposition on the BOND case (issue 3, item 8).

Run under MPI with 1 and then 2 ranks; each run appends its rows to the JSON file, and once both
are there the speed-up and efficiency are printed:

    mpiexec -n 1 python benchmarks/scaling.py
    mpiexec -n 2 python benchmarks/scaling.py

Strong: n = 60 (216,000 elements) on every rank count. Weak: n^3 = 40^3 elements per rank, the
domain growing along y (the slab axis; loading along x). 100 warm-up and 2000 timed steps each.
"""
import argparse
import json
import os

from bench_bond import time_case, write
from bond_case import bond_deck

from pardem.parallel.communicator import Communicator


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--strong-n", type=int, default=60)
    p.add_argument("--weak-n", type=int, default=40)
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "scaling.json"))
    args = p.parse_args()
    comm = Communicator()
    P = comm.size
    n, w = args.strong_n, args.weak_n
    strong = {"kind": "strong", "n": n, **time_case(comm, bond_deck(n, n, n), args.warmup, args.steps)}
    weak = {"kind": "weak", "n_per_rank": w, **time_case(comm, bond_deck(w, w * P, w), args.warmup, args.steps)}
    if not comm.is_root:
        return
    old = []
    if os.path.exists(args.out):
        with open(args.out) as fh:
            old = [r for r in json.load(fh)["results"] if r["ranks"] != P]
    rows = sorted(old + [strong, weak], key=lambda r: (r["kind"], r["ranks"]))
    for r in (strong, weak):
        split = ", ".join(f"{c:.2f}/{m:.2f}" for c, m in zip(r["seconds_computing_per_rank"],
                                                            r["seconds_communicating_per_rank"]))
        print(f"{r['kind']:6s} {P} rank(s): {r['elements']:8d} elements  {1e3 * r['seconds_per_step']:7.3f} ms/step  "
              f"{r['element_steps_per_second']:.3e} element-steps/s  compute/comm s per rank: {split}")
    summary = {}
    one = {r["kind"]: r for r in rows if r["ranks"] == 1}
    for r in rows:
        if r["ranks"] > 1 and r["kind"] in one:
            base = one[r["kind"]]["seconds_per_step"]
            if r["kind"] == "strong":
                summary[f"strong_speedup_{r['ranks']}"] = base / r["seconds_per_step"]
            else:
                summary[f"weak_efficiency_{r['ranks']}"] = base / r["seconds_per_step"]
    for k, v in summary.items():
        print(f"{k} = {v:.3f}")
    write(args.out, {"benchmark": "scaling", "results": rows, "summary": summary})


if __name__ == "__main__":
    main()
