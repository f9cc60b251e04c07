"""The figures of the anisotropy study (``anisotropy.png``) and of the calibration's verification
(``calibration.png``). Need matplotlib (``pip install 'pardem[plot]'``).

Anisotropy study: one row per domain kind: E_L^D/E_R^D and E_L^D/E_T^D against the bond ratios (one line per law,
error bars = standard deviation over the realisations, dotted: domain ratio = bond ratio), and the
off-axis modulus E(xi) [MPa] with Hankinson's prediction from E(0) and E(90), the orthotropic curve
through E(0), E(90) with K fitted to the other angles and, for the ordered lattice, the infinite lattice's orthotropic curve.
"""
import numpy as np

LAW_COLOURS = {"TOR": "C0", "hankinson": "C1", "linear": "C2", "spherical": "C3", "spherical_normalised": "C4"}
# hollow markers of decreasing size and distinct dashes: curves that coincide stay visible
LAW_STYLES = {"TOR": ("o", 9.0, "-"), "hankinson": ("s", 7.0, "--"), "linear": ("^", 5.5, "-."),
              "spherical": ("D", 4.0, ":"), "spherical_normalised": ("v", 3.0, (0, (1, 3)))}
COINCIDE_RTOL = 1e-9     # curves equal to this relative tolerance are named as coinciding


def coinciding(curves, rtol=COINCIDE_RTOL):
    """Groups (lists of names, in the given order) of the curves ``{name: (x, y)}`` that are the
    same (equal x, y equal to ``rtol``, NaN = NaN), groups of one left out."""
    groups = []
    for name, (x, y) in curves.items():
        for g in groups:
            x0, y0 = curves[g[0]]
            if (np.shape(x0) == np.shape(x) and np.array_equal(x0, x, equal_nan=True)
                    and np.allclose(y0, y, rtol=rtol, atol=0.0, equal_nan=True)):
                g.append(name)
                break
        else:
            groups.append([name])
    return [g for g in groups if len(g) > 1]


def _style(law, k):
    marker, size, dash = LAW_STYLES.get(law, ("o", max(3.0, 9.0 - 1.5 * k), "-"))
    return dict(marker=marker, ms=size, mfc="none", mew=1.1, ls=dash)


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
            curves = {}
            for k, law in enumerate(plan.laws):
                rows = data[kind][law]
                x = _column(rows, bond_key)
                y = _column(rows, f"{name}_mean")
                curves[law] = (x, y)
                ax.errorbar(x, y, yerr=_column(rows, f"{name}_std"), lw=1.2, capsize=2,
                            color=LAW_COLOURS.get(law), label=law, **_style(law, k))
                top = max(top, float(np.nanmax(x)))
            ax.plot([0, top], [0, top], color="0.5", ls=":", lw=1.0, label="domain = bond ratio")
            same = coinciding(curves)
            if same:
                ax.text(0.02, 0.98, "\n".join(" = ".join(g) + ": the same curve" for g in same),
                        transform=ax.transAxes, ha="left", va="top", fontsize="small",
                        bbox=dict(facecolor="white", edgecolor="0.6", alpha=0.9))
            ax.set_xlabel(f"bond ratio $E_L/E_{name[1]}$ [-]")
            ax.set_ylabel(f"domain ratio $E_L^D/E_{name[1]}^D$ [-]")
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
                if any(r.get("E_orthotropic_fit") is not None for r in rows):
                    ax.plot(xi, _column(rows, "E_orthotropic_fit") / 1e6, color=c, ls=":", lw=1.0)
                bad = np.array([r["E_mean"] is None for r in rows])
                if bad.any():    # failed measurements: a cross on the Hankinson curve
                    ax.plot(xi[bad], _column(rows, "E_hankinson")[bad] / 1e6, "x", color=c, ms=7)
            first = next(iter(off.get(kind, {}).values()), [])
            if any(r.get("E_orthotropic_lattice") is not None for r in first):
                ax.plot(_column(first, "xi_deg"), _column(first, "E_orthotropic_lattice") / 1e6, color="k",
                        lw=1.4, alpha=0.6, label="orthotropic, infinite lattice")
            ax.set_xlabel(r"tilt $\xi$ of L from the loading axis [deg]")
            ax.set_ylabel(r"$E(\xi)$ [MPa]")
            ax.set_yscale("log")
            ax.set_title(f"{kind}: off-axis at $E_L/E_R$ = {plan.offaxis_ratio:g}\ndashed: Hankinson, "
                         f"dotted: orthotropic fit; x: failed",
                         fontsize="small")
            ax.grid(True, lw=0.4, alpha=0.5)
            ax.legend(fontsize="small")
    fig.savefig(path, dpi=110)


def plot_calibration(verification, path):
    """Write the calibration's verification figure to ``path``: the stress [Pa] of every run against
    its strain [-] (compressions: mean plate stress against axial strain; shears: sigma_ab against
    gamma), with the target slope (dashed) and the lattice's predicted slope (dotted).
    ``verification``: the ``verification`` dict of ``pardem.drivers.calibrate``'s report."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2, squeeze=False)[0]
    panels = {"compression": axes[0], "shear": axes[1]}
    for k, (name, row) in enumerate(verification["quantities"].items()):
        rec = verification["runs"][name]
        ax = panels[row["kind"]]
        c = f"C{k % 10}"
        x = np.asarray(rec["curve"]["strain"], dtype=float)
        y = np.asarray(rec["curve"]["stress"], dtype=float)
        ax.plot(1e3 * x, y / 1e6, color=c, lw=1.4, label=f"{name}: {row['measured'] / 1e6:.4g} MPa")
        top = float(np.nanmax(x)) if len(x) else 0.0
        line = np.array([0.0, top])
        ax.plot(1e3 * line, row["target"] * line / 1e6, color=c, ls="--", lw=0.9)
        ax.plot(1e3 * line, row["predicted"] * line / 1e6, color=c, ls=":", lw=0.9)
    for kind, ax in panels.items():
        ax.set_xlabel(r"axial strain (compression) [$10^{-3}$]" if kind == "compression" else
                      r"shear strain $\gamma$ [$10^{-3}$]")
        ax.set_ylabel("mean plate stress [MPa]" if kind == "compression" else r"shear stress $\sigma_{ab}$ [MPa]")
        ax.set_title(f"{kind}: dashed target, dotted lattice prediction", fontsize="medium")
        ax.grid(True, lw=0.4, alpha=0.5)
        if ax.lines:
            ax.legend(fontsize="small")
    fig.suptitle(f"calibration check (relations {verification['relations']})", fontsize="medium")
    fig.savefig(path, dpi=110)
