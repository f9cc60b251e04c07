"""The triaxial driver's figure (``triaxial.png``): the deviator, the volumetric strain and the
broken cement fraction against the axial strain. Needs matplotlib (optional)."""
from pardem.io.figures import pyplot


def plot(path, rows, pc):
    plt = pyplot("triaxial.png")
    if plt is None:
        return
    ea = [100 * r["eps_axial"] for r in rows]
    fig, ax = plt.subplots(3, 1, figsize=(6, 8), sharex=True)
    ax[0].plot(ea, [r["q"] / pc for r in rows])
    ax[0].set_ylabel("q / pc [-]")
    ax[1].plot(ea, [100 * r["eps_vol"] for r in rows])
    ax[1].set_ylabel("eps_v [%] (contraction +)")
    ax[2].plot(ea, [r["broken_fraction"] for r in rows])
    ax[2].set_ylabel("broken cement fraction [-]")
    ax[2].set_xlabel("axial strain [%]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].set_title(f"cemented triaxial test, pc = {pc:.3g} Pa")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
