"""Checkpoint write and restart throughput (issue 4, item 7).

BOND case lattices of n^3 elements (n = 60, 100: one million elements). Each rank count is one run,
appending its rows to the JSON file:

    mpiexec -n 1 python benchmarks/bench_checkpoint.py
    mpiexec -n 2 python benchmarks/bench_checkpoint.py

Write: a checkpoint of the built case (collective MPI-IO with 2 ranks), timed from the call to the
renamed, fsynced file; MB/s = file size / seconds. Restart: ``restore_case`` of that file on the
same ranks (validation, reading, slab cuts, ghosts), i.e. what ``--restart`` does before stepping.
Files go to a scratch directory next to the results (same disk as the runs) and are deleted.
"""
import argparse
import json
import os
import shutil
import time

from bond_case import bond_deck

from pardem.protocols.compression import build_case, checkpoint_payload, restore_case
from pardem.io.checkpoint import write_checkpoint
from pardem.parallel.communicator import Communicator


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[60, 100])
    here = os.path.dirname(os.path.abspath(__file__))
    p.add_argument("--out", default=os.path.join(here, "results", "bench_checkpoint.json"))
    p.add_argument("--scratch", default=os.path.join(here, "results", "scratch"))
    args = p.parse_args()
    comm = Communicator()
    rows = []
    for n in args.sizes:
        deck = bond_deck(n, n, n)
        case = build_case(comm, deck, steps=1)
        case.sim.run(1)
        path = os.path.join(args.scratch, f"bench-n{n}-p{comm.size}.h5")
        if comm.is_root:
            os.makedirs(args.scratch, exist_ok=True)
        comm.barrier()
        groups, series, attrs = checkpoint_payload(case)
        t0 = time.perf_counter()
        write_checkpoint(path, comm, groups, series, attrs)
        t_write = comm.max(time.perf_counter() - t0)
        size = os.path.getsize(path)
        del case
        comm.barrier()
        t0 = time.perf_counter()
        restored = restore_case(comm, deck, path)
        t_read = comm.max(time.perf_counter() - t0)
        assert int(comm.sum(restored.sim.elements.n_owned)) == n**3
        row = {"n": n, "elements": n**3, "ranks": comm.size, "file_bytes": size,
               "write_seconds": t_write, "write_MB_per_s": size / t_write / 1e6,
               "restart_seconds": t_read, "read_MB_per_s": size / t_read / 1e6}
        rows.append(row)
        if comm.is_root:
            print(f"n = {n:3d} ({n**3} elements) on {comm.size} rank(s): file {size / 1e6:.1f} MB, write "
                  f"{t_write:.3f} s ({row['write_MB_per_s']:.0f} MB/s), restart {t_read:.3f} s "
                  f"({row['read_MB_per_s']:.0f} MB/s)", flush=True)
            os.remove(path)
        del restored
        comm.barrier()
    if comm.is_root:
        shutil.rmtree(args.scratch, ignore_errors=True)
        old = []
        if os.path.exists(args.out):
            with open(args.out) as fh:
                old = [r for r in json.load(fh)["results"] if r["ranks"] != comm.size]
        with open(args.out, "w") as fh:
            json.dump({"benchmark": "checkpoint", "results": sorted(old + rows, key=lambda r: (r["n"], r["ranks"]))},
                      fh, indent=2)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
