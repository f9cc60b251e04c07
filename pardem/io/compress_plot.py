"""The compress run's figure (``force_strain.png``): axial stress against axial strain and the
lateral strains, from the run folder's ``series.csv`` (or ``series.h5``) and ``summary.json``.
Needs matplotlib (optional). The command is ``python -m pardem.drivers.plot``."""
import json
import math
import os

import numpy as np

from pardem.io.figures import banner, truncation_note

from pardem.io.series import read_series
from pardem.io.series_h5 import read_series_h5

SUMMARY_KEYS = ("cross_section", "loading_axis")


def load_run(directory):
    """(series as a dict of float arrays, summary dict) of a run directory; ValueError (one line)
    if unusable."""
    if not os.path.isdir(directory):
        raise ValueError(f"{directory}: no such directory: expected the output directory of a compress run")
    summary_path = os.path.join(directory, "summary.json")
    try:
        with open(summary_path) as fh:
            summary = json.load(fh)
    except FileNotFoundError:
        raise ValueError(f"{summary_path} not found: expected the output directory of a compress run") from None
    except (OSError, ValueError) as err:
        raise ValueError(f"{summary_path}: cannot read it as JSON ({err})") from None
    missing = [k for k in SUMMARY_KEYS if k not in summary]
    if missing or summary.get("loading_axis") not in ("x", "y", "z"):
        raise ValueError(f"{summary_path} lacks {', '.join(missing) or 'a loading_axis x, y or z'}: "
                         f"expected the summary of a compress run")
    csv_path, h5_path = os.path.join(directory, "series.csv"), os.path.join(directory, "series.h5")
    try:
        if os.path.exists(csv_path):
            path, raw = csv_path, read_series(csv_path)
        elif os.path.exists(h5_path):
            path, raw = h5_path, read_series_h5(h5_path)
        else:
            raise ValueError(f"{directory} holds neither series.csv nor series.h5: "
                             f"expected the output directory of a compress run")
    except (OSError, ValueError, KeyError) as err:
        raise ValueError(f"cannot read the series in {directory}: {err}") from None
    series = {k: np.asarray(v, dtype=np.float64) for k, v in raw.items()}
    if len(series["time"]) == 0:
        raise ValueError(f"{path} holds no samples")
    return series, summary


def _finite(value):
    return isinstance(value, (int, float)) and math.isfinite(value)


def _mpa(value):
    return f"{value / 1e6:.4g} MPa" if _finite(value) else "n/a"


def plot(series, summary, out):
    """Write the two-panel figure to ``out`` (any format matplotlib knows from the suffix)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    a = summary["loading_axis"]
    others = [b for b in "xyz" if b != a]
    S = float(summary["cross_section"])
    strain = -100.0 * series[f"eps_{a}{a}"]               # axial strain, % (compression positive)
    fixed = series["force_fixed"] / S / 1e6                # MPa
    moving = series["force_moving"] / S / 1e6
    mean = 0.5 * (fixed + moving)

    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)

    left.plot(strain, mean, color="C0", lw=2.0, label="mean of the plates")
    left.plot(strain, fixed, color="C1", lw=0.8, label="fixed plate")
    left.plot(strain, moving, color="C2", lw=0.8, label="moving plate")
    E_an = summary.get("young_modulus_analytic")
    if _finite(E_an):
        s = np.array([0.0, max(float(np.nanmax(strain)), 0.0)])
        left.plot(s, E_an * s / 100.0 / 1e6, color="k", ls="--", lw=1.0,
                  label=rf"analytic $\pi/4\,E\,r^2$ = {_mpa(E_an)}")
    left.set_xlabel(rf"axial strain $-\varepsilon_{{{a}{a}}}$ [%]")
    left.set_ylabel(rf"axial stress $F / S$ [MPa]  (S = {S * 1e6:.4g} mm$^2$)")
    left.set_title("stress-strain")
    left.grid(True, lw=0.4, alpha=0.5)
    left.legend(loc="upper left", fontsize="small")

    for b, color, ls in zip(others, ("C3", "C4"), ("-", "--")):   # dashed: visible where they coincide
        right.plot(strain, 100.0 * series[f"eps_{b}{b}"], color=color, ls=ls, lw=1.5,
                   label=rf"$\varepsilon_{{{b}{b}}}$")
    right.axhline(0.0, color="0.6", lw=0.6)
    right.set_xlabel(rf"axial strain $-\varepsilon_{{{a}{a}}}$ [%]")
    right.set_ylabel("lateral strain [%]")
    right.set_title("lateral strains")
    right.grid(True, lw=0.4, alpha=0.5)
    right.legend(loc="best", fontsize="small")

    n_ranks = summary.get("n_ranks", "?")
    fig.suptitle(f"compression along {a}: measured E_{a} = {_mpa(summary.get('young_modulus'))} "
                 f"(quasi-static slope), {n_ranks} rank{'s' if n_ranks != 1 else ''}")
    note = truncation_note(summary)
    if note is not None:
        banner(fig, note)
    fig.savefig(out, dpi=110, **({"metadata": {"Description": note}} if note and str(out).endswith(".png") else {}))
