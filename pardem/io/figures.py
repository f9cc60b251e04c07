"""matplotlib for the figures of the drivers, optional: without it a figure is skipped with a note.

A run stopped early (``--steps``; its summary's ``finished`` false) says so on its figures:
``truncation_note(summary)`` is the text, the drivers' figures written at the end of such a run get
it as a red banner across their top and as the PNG's ``Description`` (``stamp``,
``stamp_figures``), and ``compress_plot`` draws it from the summary it reads.
"""
import os
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


def truncation_note(summary):
    """The banner of a run that stopped before its end (``summary["finished"]`` false), else None."""
    if summary.get("finished", True):
        return None
    why = summary.get("stopped") or "stopped before the end"
    return f"TRUNCATED RUN (step {summary.get('steps', '?')}): {why}; not the whole test"


def banner(fig, text):
    """Draw ``text`` as a red banner across the top of matplotlib figure ``fig``."""
    fig.text(0.5, 0.995, text, ha="center", va="top", fontsize=9, color="white", wrap=True,
             bbox=dict(boxstyle="square,pad=0.3", facecolor="firebrick", edgecolor="none"))


def stamp(path, text):
    """Overlay ``text`` as a red banner on the PNG at ``path`` (rewritten, same size) and store it
    as the PNG's ``Description``. False (nothing done) without matplotlib."""
    plt = pyplot("note on the figures")
    if plt is None:
        return False
    img = plt.imread(path)
    h, w = img.shape[:2]
    dpi = 100.0
    fig = plt.figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    ax = fig.add_axes([0.0, 0.0, 1.0, 1.0])
    ax.imshow(img, interpolation="none")
    ax.axis("off")
    banner(fig, text)
    fig.savefig(path, dpi=dpi, metadata={"Description": text})
    plt.close(fig)
    return True


def png_times(directory):
    """``{name: mtime_ns}`` of the ``*.png`` files directly in ``directory``."""
    return {e.name: e.stat().st_mtime_ns for e in os.scandir(directory)
            if e.name.endswith(".png") and e.is_file()}


def stamp_figures(directory, before, text):
    """``stamp`` every ``*.png`` directly in ``directory`` that is new or changed since ``before``
    (``png_times`` taken earlier): the figures a run's end wrote. Returns their names."""
    done = []
    for name, t in sorted(png_times(directory).items()):
        if before.get(name) != t and stamp(os.path.join(directory, name), text):
            done.append(name)
    return done
