"""Ghosts per rank and bytes exchanged per step: slabs [P, 1, 1] against the 3D grid, on paper.

The case: a uniform dense packing of monodisperse spheres of radius R, the face-centred cubic
packing of touching spheres (lattice constant a = 2 sqrt(2) R, 4 m^3 spheres in a periodic cube of
edge m a), contact range 2 R plus the default skin 0.2 R, so the ghost range r = 2.2 R. The grid is
``pardem.parallel.grid.choose_grid`` (even cuts); slabs are cut along x.

Counted exactly, for every rank: a rank's ghosts are the images of the other ranks' spheres in its
subdomain grown by r along the cut axes (``GridDecomposition.staged_ghosts``, the rows the staged
exchange receives from other ranks; along an uncut periodic axis a rank's own images need no
message, the neighbour list finds them). Each of the 4 sublattices of the FCC packing is a product
of 1D lattices, so the count in a box is a product of three 1D counts, exact in rational arithmetic:
O(1) per rank, so 4096 ranks of 10^7 spheres take no time. ``--check`` compares these formula
counts with the bookkeeping itself (``staged_ghosts`` over the explicit lattice, every rank
simulated in one process) at small sizes: they must be equal, sphere for sphere.

Model (for the weak-scaling series and as a check on the lattice): a uniform density n = N / V,
ghosts = n (prod_a (w_a + 2 r [a cut]) - prod_a w_a), w_a the subdomain's edges.

Bytes per step: the per-step refresh (``forward``) sends x, v, w of every ghost, 9 doubles = 72 B
(13 = 104 B with bonds, which also need q); counted as the bytes a rank receives. Messages: 2 per
step for slabs, 6 for the grid (staged: 3 rounds one after the other, the two directions of a
round at once).

Weak-scaling estimate, per step and rank: t = c n_owned (1 + delta) + rounds * latency + bytes /
bandwidth + allreduce, where c [s] is the per-element cost on one core, delta the work of the
boundary pairs computed on both sides (pardem's scheme: a pair with a ghost end is computed by both
ranks; pairs crossing a plane per unit area of an isotropic packing: n Z d / 4 with d = 2 R, so
delta = A n d / (4 n_owned), A the rank's exchanging faces' area), and the allreduce of the rebuild
check every step costs log2(P) latencies (recursive doubling). Rebuilds (migration, borders) are left out: they come
every 15-40 steps and cost about one step. Parallel efficiency = c N / P / t.

Usage: ``python benchmarks/decomposition_counts.py`` (the full table, seconds) or ``--check-only``.
"""
import argparse
import json
import math
import os
import sys
from fractions import Fraction

import numpy as np

from pardem.parallel.grid import GridDecomposition, choose_grid
from pardem.parallel.slab_comm import GHOST_WIDTH, GHOST_WIDTH_NO_BONDS

HERE = os.path.dirname(os.path.abspath(__file__))
# (100) offsets of the 4 sublattices, in half lattice constants
SUBLATTICES = ((0, 0, 0), (1, 1, 0), (1, 0, 1), (0, 1, 1))
# measured: GRAN (Hertz-Mindlin, periodic lattice of touching spheres) n = 40, 64,000 spheres, one
# rank, 1.28e7 element-steps/s (benchmarks/results/compare_peers_2026-12-07b_gran.md)
GRAN_COST = 1.0 / 1.28e7


def cells_for(n_elements):
    """FCC cube of m cells (4 m^3 spheres) nearest to ``n_elements``."""
    return max(1, round((n_elements / 4.0) ** (1.0 / 3.0)))


def _count_1d(lo, hi, offset, m):
    """Integers u = offset (mod 2) with lo <= u < hi (half lattice constants, exact Fractions),
    all periodic images included: the caller keeps hi - lo <= 3 m (images -1, 0, +1)."""
    return math.ceil((hi - offset) / 2) - math.ceil((lo - offset) / 2)


class Lattice:
    """The FCC cube of ``m`` cells in half lattice constants (edge 2 m), spheres of radius R = a /
    (2 sqrt 2), i.e. sqrt(2) / 2 half-units, ghost range ``r_over_R`` R."""

    def __init__(self, m, r_over_R):
        self.m = int(m)
        self.edge = Fraction(2 * self.m)
        self.R = math.sqrt(2.0) / 2.0
        self.r = Fraction(r_over_R * self.R)        # exact binary value of the float

    @property
    def n(self):
        return 4 * self.m ** 3

    def positions(self):
        k = np.arange(self.m)
        base = np.stack(np.meshgrid(k, k, k, indexing="ij"), axis=-1).reshape(-1, 3) * 2.0
        return np.concatenate([base + np.array(o, dtype=float) for o in SUBLATTICES])

    def counts(self, grid):
        """Exact (owned [P], ghosts [P]) of every rank of the even grid ``grid``."""
        P = grid[0] * grid[1] * grid[2]
        owned, ghosts = np.zeros(P, dtype=np.int64), np.zeros(P, dtype=np.int64)
        for rank in range(P):
            idx = (rank % grid[0], (rank // grid[0]) % grid[1], rank // (grid[0] * grid[1]))
            own, ext = 0, 0
            for o in SUBLATTICES:
                po, pe = 1, 1
                for a in range(3):
                    lo = self.edge * idx[a] / grid[a]
                    hi = self.edge * (idx[a] + 1) / grid[a]
                    po *= _count_1d(lo, hi, o[a], self.m)
                    if grid[a] > 1:
                        pe *= _count_1d(lo - self.r, hi + self.r, o[a], self.m)
                    else:
                        pe *= _count_1d(lo, hi, o[a], self.m)
                own += po
                ext += pe
            owned[rank], ghosts[rank] = own, ext - own
        return owned, ghosts


def feasible(grid, edge, r):
    """One hop per stage: every cut axis' subdomains at least r wide."""
    return all(p == 1 or edge / p >= r for p in grid)


def model_ghosts(grid, edge, r, density):
    w = [edge / p for p in grid]
    grown = np.prod([w[a] + (2 * r if grid[a] > 1 else 0.0) for a in range(3)])
    return density * (grown - np.prod(w))


def exchange_area(grid, edge):
    w = [edge / p for p in grid]
    return sum((2 if grid[a] > 1 else 0) * np.prod([w[b] for b in range(3) if b != a]) for a in range(3))


def estimate(grid, n_elements, edge, r, d, density, cost, latency, bandwidth, width, ghosts=None):
    """Seconds per step on the busiest rank and the parallel efficiency (module docstring)."""
    P = grid[0] * grid[1] * grid[2]
    owned = n_elements / P
    g = model_ghosts(grid, edge, r, density) if ghosts is None else ghosts
    delta = exchange_area(grid, edge) * density * d / (4.0 * owned)
    cut = sum(1 for p in grid if p > 1)
    rounds = cut     # the stages along uncut axes send nothing (own images)
    t_compute = cost * owned * (1.0 + delta)
    t_exchange = rounds * latency + g * width * 8 / bandwidth
    t_reduce = math.ceil(math.log2(P)) * latency if P > 1 else 0.0
    t = t_compute + t_exchange + t_reduce
    return {"seconds_per_step": t, "compute": t_compute, "exchange": t_exchange, "allreduce": t_reduce,
            "duplicated_pair_work": delta, "efficiency": cost * owned / t}


def check(r_over_R):
    """Formula counts == the staged bookkeeping over the explicit lattice (every rank in one
    process), and how far the uniform-density model is from them."""
    out = []
    for m, grids in [(6, [(2, 1, 1), (3, 1, 1), (2, 2, 2)]), (7, [(3, 1, 1), (2, 2, 2), (3, 2, 2)]),
                     (8, [(4, 1, 1), (2, 2, 2), (4, 4, 4)]),
                     (12, [(8, 1, 1), (3, 3, 3), (4, 4, 4), (4, 2, 2)])]:
        lat = Lattice(m, r_over_R)
        x = lat.positions()
        edge = float(lat.edge)
        r = float(lat.r)
        for grid in grids:
            g = GridDecomposition(grid, [0, 0, 0], [edge] * 3, (True, True, True))
            ghosts, _ = g.staged_ghosts(x, r)
            uncut = np.array([p == 1 for p in grid])
            # rows from other ranks: drop a rank's own images along uncut axes (no message)
            staged = np.array([int(np.sum(~np.any((s != 0) & uncut, axis=1))) for _, s in
                               (ghosts[q] for q in range(g.size))])
            owned, formula = lat.counts(grid)
            if not np.array_equal(staged, formula):
                raise AssertionError(f"m = {m}, grid {grid}: staged {staged.tolist()} != formula {formula.tolist()}")
            if not np.array_equal(owned, np.bincount(g.owner(x), minlength=g.size)):
                raise AssertionError(f"m = {m}, grid {grid}: owned counts differ")
            density = lat.n / edge ** 3
            out.append({"cells": m, "elements": lat.n, "grid": list(grid), "ranks": g.size,
                        "exact_mean_ghosts": float(staged.mean()), "exact_max_ghosts": int(staged.max()),
                        "formula_equals_bookkeeping": True,
                        "model_ghosts": float(model_ghosts(grid, edge, r, density))})
    return out


def table(sizes, ranks, r_over_R, costs, latency, bandwidth, width):
    rows = []
    for n_target in sizes:
        lat = Lattice(cells_for(n_target), r_over_R)
        edge, r = float(lat.edge), float(lat.r)
        density = lat.n / edge ** 3
        d = 2.0 * lat.R
        for P in ranks:
            for kind, grid in [("slabs", (P, 1, 1)), ("grid", choose_grid(P, [edge] * 3, (True,) * 3))]:
                row = {"elements": lat.n, "ranks": P, "kind": kind, "grid": list(grid),
                       "owned_per_rank": lat.n / P}
                if not feasible(grid, edge, r):
                    row.update(feasible=False, why=f"subdomain {edge / max(grid) / lat.R:.3g} R thin, "
                                                   f"ghost range {r / lat.R:.3g} R")
                    rows.append(row)
                    continue
                owned, ghosts = lat.counts(grid)
                row.update(feasible=True, mean_ghosts=float(ghosts.mean()), max_ghosts=int(ghosts.max()),
                           model_ghosts=float(model_ghosts(grid, edge, r, density)),
                           ghosts_per_owned=float(ghosts.mean() / owned.mean()),
                           messages_per_step=2 * sum(1 for p in grid if p > 1),
                           bytes_per_step_per_rank=float(ghosts.max()) * width * 8,
                           bytes_per_step_total=float(ghosts.sum()) * width * 8,
                           estimates={f"{c:g}": estimate(grid, lat.n, edge, r, d, density, c, latency, bandwidth,
                                                         width, ghosts=float(ghosts.max())) for c in costs})
                rows.append(row)
    return rows


def weak(per_rank, ranks, r_over_R, costs, latency, bandwidth, width):
    """Fixed elements per rank, the uniform-density model (the lattice's own edge for N = n P)."""
    out = []
    R = math.sqrt(2.0) / 2.0
    density = 4.0 / 8.0            # 4 spheres per cube of edge 2 half-units
    for n in per_rank:
        for P in ranks:
            N = n * P
            edge = (N / density) ** (1.0 / 3.0)
            r = r_over_R * R
            for kind, grid in [("slabs", (P, 1, 1)), ("grid", choose_grid(P, [edge] * 3, (True,) * 3))]:
                row = {"elements_per_rank": n, "ranks": P, "kind": kind, "grid": list(grid)}
                if not feasible(grid, edge, r):
                    row["feasible"] = False
                else:
                    row["feasible"] = True
                    row["estimates"] = {f"{c:g}": estimate(grid, N, edge, r, 2 * R, density, c, latency,
                                                           bandwidth, width) for c in costs}
                out.append(row)
    return out


def markdown(res):
    a = res["arguments"]
    lines = ["# Ghosts and bytes per step: slabs against the 3D grid", "",
             "`python benchmarks/decomposition_counts.py` (`benchmarks/decomposition_counts.py` states the "
             "case and the models). FCC packing of touching spheres of radius R in a periodic cube, ghost "
             f"range {a['ghost_range_R']} R (2 R + skin 0.2 R), even cuts, {a['doubles_per_ghost']} doubles "
             "(x, v, w) per ghost per step. Ghosts counted exactly for every rank (mean and busiest rank); "
             "model: uniform density.", "",
             "| elements | ranks | decomposition | owned/rank | ghosts/rank (mean) | busiest | model | "
             "ghosts/owned | messages | kB/step busiest rank | MB/step all ranks |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in res["table"]:
        g = "x".join(map(str, r["grid"]))
        if not r["feasible"]:
            lines.append(f"| {r['elements']:,} | {r['ranks']} | {r['kind']} {g} | {r['owned_per_rank']:,.0f} | "
                         f"impossible: {r['why']} | | | | | | |")
            continue
        lines.append(f"| {r['elements']:,} | {r['ranks']} | {r['kind']} {g} | {r['owned_per_rank']:,.0f} | "
                     f"{r['mean_ghosts']:,.0f} | {r['max_ghosts']:,} | {r['model_ghosts']:,.0f} | "
                     f"{r['ghosts_per_owned']:.2f} | {r['messages_per_step']} | "
                     f"{r['bytes_per_step_per_rank'] / 1e3:,.1f} | {r['bytes_per_step_total'] / 1e6:,.1f} |")
    costs = list(res["arguments"]["element_cost_s"])
    lines += ["", f"Estimated step (busiest rank) and parallel efficiency, network latency "
              f"{a['latency_s'] * 1e6:g} us, bandwidth {a['bandwidth_Bps'] / 1e9:g} GB/s; per-element cost c "
              f"[s] on one core ({a['cost_source']}):", "",
              "| elements | ranks | decomposition | " + " | ".join(f"c = {c:g} s: us/step, efficiency" for c in costs)
              + " | duplicated pair work |", "| --- | --- | --- | " + " | ".join("---" for _ in costs) + " | --- |"]
    for r in res["table"]:
        if not r["feasible"]:
            continue
        est = [r["estimates"][f"{c:g}"] for c in costs]
        lines.append(f"| {r['elements']:,} | {r['ranks']} | {r['kind']} | "
                     + " | ".join(f"{e['seconds_per_step'] * 1e6:,.1f}, {e['efficiency']:.2f}" for e in est)
                     + f" | {est[0]['duplicated_pair_work']:.1%} |")
    lines += ["", "Weak scaling (fixed elements per rank, uniform-density model), efficiency:", "",
              "| elements/rank | decomposition | " + " | ".join(f"P = {P}" for P in a["ranks"]) + " |",
              "| --- | --- | " + " | ".join("---" for _ in a["ranks"]) + " |"]
    for n in a["weak_per_rank"]:
        for kind in ("slabs", "grid"):
            cells = []
            for P in a["ranks"]:
                row = next(w for w in res["weak"] if w["elements_per_rank"] == n and w["ranks"] == P and w["kind"] == kind)
                cells.append(" / ".join(f"{row['estimates'][f'{c:g}']['efficiency']:.2f}" for c in costs)
                             if row["feasible"] else "impossible")
            lines.append(f"| {n:,} | {kind} | " + " | ".join(cells) + " |")
    lines += ["", f"(each cell: efficiency for c = {' / '.join(f'{c:g}' for c in costs)} s)", "",
              "Check (`--check-only`): the lattice formula equals the staged-exchange bookkeeping "
              "(`GridDecomposition.staged_ghosts`, every rank simulated in one process) rank by rank; model / exact:", "",
              "| elements | grid | exact mean ghosts | model | model / exact |", "| --- | --- | --- | --- | --- |"]
    for c in res["checks"]:
        lines.append(f"| {c['elements']:,} | {'x'.join(map(str, c['grid']))} | {c['exact_mean_ghosts']:,.1f} | "
                     f"{c['model_ghosts']:,.1f} | {c['model_ghosts'] / c['exact_mean_ghosts']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--elements", type=float, nargs="+", default=[1e6, 1e7])
    ap.add_argument("--ranks", type=int, nargs="+", default=[8, 64, 512, 4096])
    ap.add_argument("--skin-radii", type=float, default=0.2, help="skin [R] (pardem's default 0.2)")
    ap.add_argument("--element-cost", type=float, nargs="+", default=[GRAN_COST, 2.5e-6],
                    help="seconds per element-step on one core (default: the measured GRAN figure, and 2.5e-6)")
    ap.add_argument("--latency", type=float, default=2e-6, help="[s] per message round")
    ap.add_argument("--bandwidth", type=float, default=10e9, help="[B/s] per rank")
    ap.add_argument("--bonds", action="store_true", help="13 doubles per ghost (q too)")
    ap.add_argument("--weak-per-rank", type=int, nargs="+", default=[2_441, 19_531, 156_250])
    ap.add_argument("--check-only", action="store_true", help="only the exact-count check at small sizes")
    ap.add_argument("--json", default=os.path.join(HERE, "results", "decomposition_counts.json"))
    ap.add_argument("--md", default=os.path.join(HERE, "results", "decomposition_counts.md"))
    args = ap.parse_args(argv)
    r_over_R = 2.0 + args.skin_radii
    width = GHOST_WIDTH if args.bonds else GHOST_WIDTH_NO_BONDS
    res = {"arguments": {"elements": args.elements, "ranks": args.ranks, "ghost_range_R": r_over_R,
                         "element_cost_s": args.element_cost,
                         "cost_source": f"{GRAN_COST:.3g} s = GRAN n = 40 on one core, 1.28e7 element-steps/s, "
                                        "benchmarks/results/compare_peers_2026-12-07b_gran.md; 2.5e-6 s the "
                                        "figure the task gave",
                         "latency_s": args.latency, "bandwidth_Bps": args.bandwidth, "doubles_per_ghost": width,
                         "weak_per_rank": args.weak_per_rank},
           "checks": check(r_over_R)}
    if not args.check_only:
        res["table"] = table(args.elements, args.ranks, r_over_R, args.element_cost, args.latency,
                             args.bandwidth, width)
        res["weak"] = weak(args.weak_per_rank, args.ranks, r_over_R, args.element_cost, args.latency,
                           args.bandwidth, width)
    with open(args.json, "w") as fh:
        json.dump(res, fh, indent=1)
    if not args.check_only:
        with open(args.md, "w") as fh:
            fh.write(markdown(res))
        print(markdown(res))
    else:
        for c in res["checks"]:
            print(c)
    return 0


if __name__ == "__main__":
    sys.exit(main())
