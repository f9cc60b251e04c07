"""The iteration history figure of the compact-domain calibration (``calibration_history.png``)."""
import numpy as np


def plot_compact_history(result, path):
    """Write the history of ``pardem.protocols.compact_calibration.calibrate_compact``'s ``result`` to
    ``path``: left, the relative error [%] of the mean measured modulus of every target against the
    iteration, with the tolerance band; right, the bond moduli E^mu [Pa] (log scale) and the bond radius
    ratios [-] (right axis) used at each iteration. Raises ImportError without matplotlib."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    hist = result["history"]
    it = np.array([h["iteration"] for h in hist])
    fig = Figure(figsize=(10.0, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2, squeeze=False)[0]
    tol = 100.0 * result["tolerance"]
    left.axhspan(-tol, tol, color="0.85", label=f"tolerance +-{tol:g} %")
    for k, name in enumerate(result["targets"]):
        err = np.array([100.0 * h["relative_error"][name] for h in hist])
        left.plot(it, err, "o-", color=f"C{k}", lw=1.2, ms=4,
                  label=f"{name} (target {result['targets'][name] / 1e6:.4g} MPa)")
    left.axhline(0.0, color="k", lw=0.6)
    left.set_xlabel("iteration [-]")
    left.set_ylabel("mean measured / target - 1 [%]")
    span = max(3.0 * tol, float(np.nanmax(np.abs([100.0 * v for h in hist for v in h["relative_error"].values()]))))
    left.set_yscale("symlog", linthresh=max(tol, 1e-3))
    left.set_ylim(-1.1 * span, 1.1 * span)
    left.grid(True, lw=0.4, alpha=0.5)
    left.legend(fontsize="small")
    left.set_title(f"measured moduli over {len(result['seeds'])} realisation(s)", fontsize="medium")
    for k, d in enumerate("LRT"):
        right.semilogy(it, [h["young"][k] for h in hist], "s-", color=f"C{k}", lw=1.2, ms=4, label=f"E_{d}^mu")
    right.set_xlabel("iteration [-]")
    right.set_ylabel("bond Young's modulus E^mu [Pa]")
    twin = right.twinx()
    for k, d in enumerate("LRT"):
        twin.plot(it, [h["radius_ratio"][k] for h in hist], "^--", color=f"C{k}", lw=0.9, ms=4, label=f"r_{d}")
    twin.set_ylabel("bond radius ratio r [-] (dashed)")
    right.grid(True, lw=0.4, alpha=0.5)
    lines = right.get_lines() + twin.get_lines()
    right.legend(lines, [ln.get_label() for ln in lines], fontsize="small")
    right.set_title("bond parameters measured at each iteration", fontsize="medium")
    fig.suptitle("compact-domain calibration by measurement ("
                 + ("converged" if result["converged"] else "NOT converged") + ")", fontsize="medium")
    fig.savefig(path, dpi=110)
