"""Force-strain plot of a compression run.

    python -m pardem.drivers.plot DIR [--out FILE.png]

Reads ``DIR/series.csv`` (or ``DIR/series.h5`` when there is no CSV) and ``DIR/summary.json`` and
writes ``DIR/force_strain.png``: axial stress against axial strain (left) and the lateral strains
against the axial strain (right). Needs matplotlib (``pip install 'pardem[plot]'``).
"""
import argparse
import os
import sys

from pardem.drivers.cli import EXIT_OK, fail_usage
from pardem.io.compress_plot import load_run, plot


def parser():
    p = argparse.ArgumentParser(
        prog="python -m pardem.drivers.plot", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="reads DIR/series.csv (or DIR/series.h5) and DIR/summary.json of a compress run\n\n"
               "exit codes: 0 ok, 1 unexpected error, 2 bad input or matplotlib missing")
    p.add_argument("dir", metavar="DIR", help="output directory of a compress run")
    p.add_argument("--out", metavar="FILE.png", help="image to write (default: DIR/force_strain.png)")
    return p


def main(argv=None):
    args = parser().parse_args(argv)
    try:
        series, summary = load_run(args.dir)
    except ValueError as err:
        fail_usage(None, str(err))
    out = args.out or os.path.join(args.dir, "force_strain.png")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        fail_usage(None, "matplotlib is not installed: pip install 'pardem[plot]'")
    try:
        plot(series, summary, out)
    except OSError as err:
        fail_usage(None, f"cannot write {out}: {err.strerror or err}")
    except ValueError as err:      # e.g. an image format matplotlib does not know
        fail_usage(None, f"cannot write {out}: {err}")
    print(f"wrote {out}")
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
