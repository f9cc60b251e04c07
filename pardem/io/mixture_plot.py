"""The figures of the mixture study (``pardem.protocols.mixture_study``). Need matplotlib.

``mixture.png``: six panels against the concentration of small grains, one line per size ratio
(error bars: standard deviation over the realisations; the monodisperse ratio 1 as a dotted
horizontal line): Z without rattlers, rattler fraction, solid fraction, the order parameter, the
relaxed bulk and shear moduli. ``mixture_structure.png``: the mean g(r) and the normal-force density
of every point.
"""
import numpy as np

PANELS = (("Z_no_rattlers", "coordination without rattlers $Z'$ [-]", 1.0),
          ("rattler_fraction", "rattler fraction [-]", 1.0),
          ("solid_fraction", "solid fraction $\\phi$ [-]", 1.0),
          ("order", None, 1.0),
          ("K_relaxed", "relaxed bulk modulus $K$ [MPa]", 1e-6),
          ("mu_relaxed", "relaxed shear modulus $\\mu$ [MPa]", 1e-6))


def _value(row, key, scale):
    v = row.get(key)
    return np.nan if v is None else v * scale


def _figure(ncols, nrows, size):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, np.atleast_2d(fig.subplots(nrows, ncols, squeeze=False))


def plot_summary(summary, path):
    """The six measures against concentration (see the module docstring) to ``path``."""
    plan, points = summary["plan"], summary["points"]
    order = "hexatic order $|\\langle\\psi_6\\rangle|$ [-]" if summary["order_parameter"] == "psi6" \
        else "Steinhardt $Q_6$ [-]"
    fig, axes = _figure(3, 2, (13.5, 7.5))
    for ax, (key, label, scale) in zip(axes.flat, PANELS):
        for r in plan["ratios"]:
            rows = [p for p in points if p["ratio"] == r]
            y = np.array([_value(p, f"{key}_mean", scale) for p in rows])
            e = np.array([_value(p, f"{key}_std", scale) for p in rows])
            if r == 1.0:
                ax.axhline(y[0], color="0.4", ls=":", lw=1.2, label="monodisperse")
                continue
            c = [p["concentration"] for p in rows]
            ax.errorbar(c, y, yerr=e, marker="o", ms=4, lw=1.2, capsize=2, label=f"$R_l/R_s$ = {r:g}")
        ax.set_xlabel(f"{plan['basis']} concentration of small grains [-]")
        ax.set_ylabel(label or order)
        ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(f"bidisperse packings of {plan['n']} grains ({plan['dimension']}D) at $p_0$ = "
                 f"{plan['pressure']:g} Pa, frictionless preparation")
    fig.savefig(path, dpi=120)


def plot_structure(summary, path):
    """Mean g(r) and the normal-force density f / <f> of every point to ``path``."""
    points = [p for p in summary["points"] if "g_r" in p]
    fig, axes = _figure(2, 1, (12.0, 4.5))
    for p in points:
        label = f"$R_l/R_s$ = {p['ratio']:g}, c = {p['concentration']:g}"
        axes[0, 0].plot(p["g_r"]["r_over_d"], p["g_r"]["g"], lw=1.0, label=label)
        edges = np.asarray(p["force_density"]["edges"])
        density = np.asarray(p["force_density"]["density"], dtype=float)
        axes[0, 1].semilogy(0.5 * (edges[1:] + edges[:-1]), np.where(density > 0, density, np.nan),
                            marker=".", lw=1.0, label=label)      # empty bins left out of the log axis
    axes[0, 0].set_xlabel("distance $r / \\langle d \\rangle$ [-]")
    axes[0, 0].set_ylabel("pair distribution $g(r)$ [-]")
    axes[0, 1].set_xlabel("normal force $f_n / \\langle f_n \\rangle$ [-]")
    axes[0, 1].set_ylabel("probability density [-]")
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.savefig(path, dpi=120)
