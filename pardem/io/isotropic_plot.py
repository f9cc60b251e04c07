"""The isotropic driver's figures: the preparation and moduli series (``isotropic.png``) and the
contact force distributions (``force_distribution.png``). Need matplotlib (optional)."""
import os

from pardem.io.figures import pyplot


def series(rows, path):
    """``isotropic.png``: p / p0 and the solid fraction against the step, one colour per pressure."""
    plt = pyplot(os.path.basename(path))
    if plt is None or not rows:
        return False
    fig, ax = plt.subplots(2, 1, figsize=(6, 6), sharex=True)
    for k in sorted({r["pressure_index"] for r in rows}):
        mine = [r for r in rows if r["pressure_index"] == k]
        steps = [r["step"] for r in mine]
        ax[0].plot(steps, [r["pressure"] / r["p0"] for r in mine], ".-", ms=2,
                   label=f"p0 = {mine[0]['p0']:g} Pa")
        ax[1].plot(steps, [r["solid_fraction"] for r in mine], ".-", ms=2)
    ax[0].set_ylabel("p / p0 [-]")
    ax[0].set_yscale("symlog", linthresh=1e-3)
    ax[0].legend(fontsize=8)
    ax[1].set_ylabel("solid fraction [-] (overlaps counted)")
    ax[1].set_xlabel("step [-]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].set_title("isotropic preparation and moduli relaxations")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def force_distribution(details, path):
    """``force_distribution.png``: the distribution of the normal contact forces at each p0."""
    plt = pyplot("force_distribution.png")
    if plt is None or not details:
        return False
    fig, ax = plt.subplots(figsize=(6, 4))
    for d in details:
        fd = d["force_distribution"]
        e = fd["edges"]
        mid = [0.5 * (a + b) for a, b in zip(e[:-1], e[1:])]
        ax.semilogy(mid, [v if v > 0 else float("nan") for v in fd["density"]], "o-", ms=3,
                    label=f"p0 = {d['p0']:g} Pa")
    ax.set_xlabel("f_n / <f_n> [-]")
    ax.set_ylabel("probability density [-]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True
