"""Neighbour-search benchmark: Verlet-list build on a jittered simple cubic lattice.

n^3 monodisperse elements (n = 40, 60: 64,000 and 216,000), R = 0.1 mm, lattice spacing 1.998 R,
each centre moved by a uniform random offset of up to +-``jitter`` R per axis, periodic in x, y and
z (box = n spacings), skin 0.2 R (the "auto" skin of the compression case). All rows owned, one
core. Each size is built once to compile and warm the buffers, then ``--repeat`` times:

* ``seconds_per_build``: ``build_pairs`` from scratch (fresh buffers, the capacity guess included);
* ``seconds_per_rebuild``: ``VerletList.rebuild`` with buffers kept from the previous build (the
  case in a run);
* ``seconds_per_check``: ``VerletList.needs_rebuild`` (the per-step displacement test).

    python benchmarks/bench_neighbours.py [--sizes 40 60] [--repeat 10] [--out FILE.json]

Prints and writes JSON with the median times, the number of pairs and the number of cells.
"""
import argparse
import json
import os
import platform
import time

import numpy as np

from pardem.physics.neighbours import VerletList, build_pairs

R = 1.0e-4
SPACING = 1.998 * R


def lattice(n, jitter, seed=0):
    """Jittered n^3 simple cubic lattice: positions [n^3, 3] [m], gids, box length [m]."""
    g = (np.arange(n) + 0.5) * SPACING
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    x += rng.uniform(-jitter * R, jitter * R, x.shape)
    return np.ascontiguousarray(x), np.arange(x.shape[0], dtype=np.int64), n * SPACING


def median_time(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), float(np.min(times))


def time_size(n, skin, jitter, repeat):
    x, gid, L = lattice(n, jitter)
    radius = np.full(x.shape[0], R)
    N = x.shape[0]
    lo, hi = np.zeros(3), np.full(3, L)
    per = (True, True, True)
    pairs, _ = build_pairs(x, radius, gid, N, N, skin, lo, hi, per)   # compile and warm up
    build, build_min = median_time(lambda: build_pairs(x, radius, gid, N, N, skin, lo, hi, per), repeat)
    vl = VerletList(skin, per, lo, hi)
    vl.rebuild(x, radius, gid, N)
    rebuild, rebuild_min = median_time(lambda: vl.rebuild(x, radius, gid, N), repeat)
    check, _ = median_time(lambda: vl.needs_rebuild(x), repeat)
    return {
        "n": n, "elements": N, "radius": R, "spacing": SPACING, "jitter": jitter * R, "skin": skin,
        "periodic": "xyz", "pairs": int(len(pairs)), "pairs_per_element": len(pairs) / N,
        "cells": vl.grid.n_cells, "cells_per_axis": [int(c) for c in vl.grid.nc],
        "seconds_per_build": build, "seconds_per_build_min": build_min,
        "seconds_per_rebuild": rebuild, "seconds_per_rebuild_min": rebuild_min,
        "seconds_per_check": check, "repeat": repeat,
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[40, 60])
    p.add_argument("--skin", type=float, default=0.2, help="skin in units of R")
    p.add_argument("--jitter", type=float, default=0.01, help="largest offset per axis in units of R")
    p.add_argument("--repeat", type=int, default=10)
    p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "bench_neighbours.json"))
    args = p.parse_args()
    results = []
    for n in args.sizes:
        row = time_size(n, args.skin * R, args.jitter, args.repeat)
        results.append(row)
        print(f"n = {n:3d}: {row['elements']:8d} elements {row['pairs']:8d} pairs {row['cells']:8d} cells  "
              f"build {1e3 * row['seconds_per_build']:7.2f} ms  rebuild {1e3 * row['seconds_per_rebuild']:7.2f} ms  "
              f"check {1e3 * row['seconds_per_check']:6.3f} ms", flush=True)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump({"benchmark": "neighbours", "results": results, "machine": platform.machine(),
                   "cpus": os.cpu_count()}, fh, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
