"""A longer run of the fuzz generators of the test suite: every driver's deck
(``tests/test_fuzz_decks.py``) and the Python builders (``tests/test_fuzz_builders.py``).

    python benchmarks/fuzz_probe.py [--decks N] [--systems N] [--seed S]

Each generated deck is checked (``load_or_refuse``: it loads, or one DeckError line naming a key);
each generated ``System`` is built and run 3 steps (``build_or_refuse``: it runs, stops unstable,
or one ValueError line naming an argument). Prints the cases tried, the refusals, and every crash
(any other exception, or a refusal that is not one line naming a key) with its input.
"""
import argparse
import collections
import os
import sys
import time
import traceback

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))

from hypothesis import HealthCheck, given, settings  # noqa: E402

import test_fuzz_builders as fb  # noqa: E402
import test_fuzz_decks as fd  # noqa: E402


def probe(name, strategy, check, n, seed, crashes, counts):
    @settings(max_examples=n, deadline=None, database=None, derandomize=seed is None,
              suppress_health_check=list(HealthCheck))
    @given(case=strategy)
    def run(case):
        try:
            out = check(case)
            counts[name, "refused" if isinstance(out, str) and out != "built" and out != "unstable"
                   else "ok"] += 1
        except Exception as exc:   # noqa: BLE001 - a crash is what the probe looks for
            counts[name, "crash"] += 1
            where = traceback.extract_tb(exc.__traceback__)[-1]
            crashes.append((name, f"{type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''}",
                            f"{os.path.relpath(where.filename)}:{where.lineno}", repr(case)[:400]))
    run()


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--decks", type=int, default=1000, help="generated decks per driver")
    p.add_argument("--systems", type=int, default=1000, help="generated Python systems")
    p.add_argument("--seed", type=int, default=None, help="(unused: the draws are derandomised)")
    args = p.parse_args()
    crashes, counts = [], collections.Counter()
    t0 = time.perf_counter()
    for driver in fd.DRIVERS:
        schema = fd.DRIVERS[driver][0]
        probe(f"deck:{driver}", fd.raw_decks(schema), lambda raw, d=driver: fd.load_or_refuse(d, raw),
              args.decks, args.seed, crashes, counts)
    probe("python:build", fb.systems(), fb.build_or_refuse, args.systems, args.seed, crashes, counts)
    names = sorted({k[0] for k in counts})
    total = sum(counts.values())
    print(f"{total} cases in {time.perf_counter() - t0:.0f} s")
    for name in names:
        print(f"  {name:20s} tried {sum(counts[name, k] for k in ('ok', 'refused', 'crash')):6d}  "
              f"accepted {counts[name, 'ok']:6d}  refused in one line {counts[name, 'refused']:6d}  "
              f"crashes {counts[name, 'crash']:4d}")
    for c in crashes:
        print("CRASH", *c, sep="\n  ")
    return 1 if crashes else 0


if __name__ == "__main__":
    sys.exit(main())
