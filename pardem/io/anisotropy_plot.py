"""The anisotropy study's figure (``anisotropy.png``). Needs matplotlib (``pip install 'pardem[plot]'``).

One row per domain kind: E_L^D/E_R^D and E_L^D/E_T^D against the bond ratios (one line per law,
error bars = standard deviation over the realisations, dotted: domain ratio = bond ratio), and the
off-axis modulus E(xi) with Hankinson's prediction from E(0) and E(90).
"""
import numpy as np

LAW_COLOURS = {"TOR": "C0", "hankinson": "C1", "linear": "C2", "spherical": "C3"}


def _column(rows, key):
    return np.array([np.nan if r[key] is None else r[key] for r in rows], dtype=float)


def plot_study(data, plan, path):
    """Write the figure of ``data`` (``anisotropy_study.summarise``) to ``path`` (format from the suffix)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    kinds = list(plan.kinds)
    off = data.get("off_axis", {})
    ncols = 3 if off else 2
    fig = Figure(figsize=(4.4 * ncols, 3.8 * len(kinds)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_2d(fig.subplots(len(kinds), ncols, squeeze=False))
    for row, kind in zip(axes, kinds):
        for ax, name, bond_key in ((row[0], "LR", "bond_LR"), (row[1], "LT", "bond_LT")):
            top = 0.0
            for law in plan.laws:
                rows = data[kind][law]
                x = _column(rows, bond_key)
                ax.errorbar(x, _column(rows, f"{name}_mean"), yerr=_column(rows, f"{name}_std"), marker="o",
                            ms=3.5, lw=1.2, capsize=2, color=LAW_COLOURS.get(law), label=law)
                top = max(top, float(np.nanmax(x)))
            ax.plot([0, top], [0, top], color="0.5", ls=":", lw=1.0, label="domain = bond ratio")
            ax.set_xlabel(f"bond ratio $E_L/E_{name[1]}$")
            ax.set_ylabel(f"domain ratio $E_L^D/E_{name[1]}^D$")
            ax.set_title(f"{kind}: $E_L^D/E_{name[1]}^D$")
            ax.grid(True, lw=0.4, alpha=0.5)
            ax.legend(fontsize="small")
        if off:
            ax = row[2]
            for law, rows in off.get(kind, {}).items():
                xi = _column(rows, "xi_deg")
                c = LAW_COLOURS.get(law)
                ax.errorbar(xi, _column(rows, "E_mean") / 1e6, yerr=_column(rows, "E_std") / 1e6, marker="o",
                            ms=3.5, lw=0, elinewidth=1.0, capsize=2, color=c, label=f"{law}")
                ax.plot(xi, _column(rows, "E_hankinson") / 1e6, color=c, ls="--", lw=1.0)
                bad = np.array([r["E_mean"] is None for r in rows])
                if bad.any():    # failed measurements: a cross on the Hankinson curve
                    ax.plot(xi[bad], _column(rows, "E_hankinson")[bad] / 1e6, "x", color=c, ms=7)
            ax.set_xlabel(r"tilt $\xi$ of L from the loading axis [deg]")
            ax.set_ylabel(r"$E(\xi)$ [MPa]")
            ax.set_yscale("log")
            ax.set_title(f"{kind}: off-axis at $E_L/E_R$ = {plan.offaxis_ratio:g}\n"
                         f"dashed: Hankinson from E(0), E(90); x: failed", fontsize="medium")
            ax.grid(True, lw=0.4, alpha=0.5)
            ax.legend(fontsize="small")
    fig.savefig(path, dpi=110)
