"""matplotlib for the figures of the drivers, optional: without it a figure is skipped with a note."""
import sys


def pyplot(what):
    """``matplotlib.pyplot`` on the file-only Agg backend (no display on compute nodes), or None
    after the note ``... so no <what>`` on stderr if matplotlib is not installed."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        sys.stderr.write(f"pardem: note: matplotlib is not installed, so no {what}\n")
        return None
    return plt
