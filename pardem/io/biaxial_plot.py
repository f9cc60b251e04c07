"""Figures and field files of the 2D biaxial test (``pardem.protocols.biaxial``), rank 0 only.

* ``curves(path, rows)``: deviator q / pc and volumetric strain against axial strain, one line per
  confining pressure (PNG, labelled axes and units);
* ``maps(path, field, title)``: the incremental shear strain and the grains' rotation increments of
  a localisation window, drawn at the grains' centres, with the detected band's centre line;
* ``write_fields(path, field, gid, radius)``: the same fields as a VTK XML unstructured grid of points
  (``radius``, ``gid``, ``shear``, ``volumetric``, ``rotation``, ``spin``, ``platen``,
  ``cements_broken`` point data) for ParaView:
  open it, then Glyph (Sphere, scale by radius) and colour by ``shear``.

matplotlib is optional: without it the PNGs are skipped with a note (``False`` returned).
"""
import sys

import numpy as np


def _pyplot():
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        return plt
    except ImportError:
        sys.stderr.write("pardem: note: matplotlib is not installed, so no biaxial figures\n")
        return None


def curves(path, rows):
    """q / pc and eps_v [%] against eps_a [%] per confining pressure (``rows``: the series)."""
    plt = _pyplot()
    if plt is None or not rows:
        return False
    fig, ax = plt.subplots(2, 1, figsize=(6, 7), sharex=True)
    for k in sorted({int(r["pressure_index"]) for r in rows}):
        rs = [r for r in rows if int(r["pressure_index"]) == k]
        ea = [100.0 * r["eps_axial"] for r in rs]
        pc = rs[0]["pc"]
        ax[0].plot(ea, [r["q"] / pc for r in rs], label=f"pc = {pc:.3g} Pa")
        ax[1].plot(ea, [100.0 * r["eps_vol"] for r in rs], label=f"pc = {pc:.3g} Pa")
    ax[0].set_ylabel("deviator q / pc [-]")
    ax[1].set_ylabel("volumetric strain eps_v [%] (contraction +)")
    ax[1].set_xlabel("axial strain eps_a [%]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    ax[0].set_title("2D biaxial test, flexible membranes")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def maps(path, field, radius, title=""):
    """Incremental shear strain [-] and grain rotation increment [rad] of a window at the grains'
    centres ``field["x"]`` [m] (drawn in mm, marker area ~ radius^2)."""
    plt = _pyplot()
    if plt is None:
        return False
    x = np.asarray(field["x"]) * 1e3
    fig, ax = plt.subplots(1, 2, figsize=(11, 5.5))
    size = (np.asarray(radius) / np.max(radius)) ** 2 * 8.0
    shear = np.where(np.isfinite(field["shear"]), field["shear"], 0.0)
    a = ax[0].scatter(x[:, 0], x[:, 1], c=shear, s=size, cmap="viridis", vmin=0.0,
                      vmax=float(np.quantile(shear, 0.98)) or None)
    fig.colorbar(a, ax=ax[0], label="incremental shear strain [-]")
    spin = np.asarray(field["spin"])
    lim = float(np.quantile(np.abs(spin), 0.98)) or 1e-12
    b = ax[1].scatter(x[:, 0], x[:, 1], c=spin, s=size, cmap="coolwarm", vmin=-lim, vmax=lim)
    fig.colorbar(b, ax=ax[1], label="grain rotation increment [rad] (counter-clockwise +)")
    band = field.get("band")
    for axis in ax:
        if band is not None:
            c, d = np.asarray(band["centre"]) * 1e3, np.asarray(band["direction"])
            span = np.ptp(x, axis=0).max()
            axis.plot([c[0] - span * d[0], c[0] + span * d[0]], [c[1] - span * d[1], c[1] + span * d[1]],
                      "k--", lw=0.8)
            axis.set_xlim(x[:, 0].min() - 0.2, x[:, 0].max() + 0.2)
            axis.set_ylim(x[:, 1].min() - 0.2, x[:, 1].max() + 0.2)
        axis.set_aspect("equal")
        axis.set_xlabel("x [mm]")
        axis.set_ylabel("y [mm]")
    fig.suptitle(title + (f"; band at {band['angle_deg']:.1f} deg, width {band['width_d']:.1f} d"
                          if band is not None else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def write_fields(path, field, gid, radius):
    """The window's fields as a VTU of points (SI units; z = 0)."""
    import meshio
    x = np.asarray(field["x"], dtype=np.float64)
    pts = np.column_stack([x, np.zeros(len(x))])
    data = {"radius": np.asarray(radius, dtype=np.float64), "gid": np.asarray(gid, dtype=np.int64),
            "shear": np.asarray(field["shear"], dtype=np.float64),
            "volumetric": np.asarray(field["volumetric"], dtype=np.float64),
            "rotation": np.asarray(field["rotation"], dtype=np.float64),
            "spin": np.asarray(field["spin"], dtype=np.float64),
            "platen": (~np.asarray(field["inside"])).astype(np.int32),
            "cements_broken": np.asarray(field.get("cements_broken", np.zeros(len(x))), dtype=np.int32)}
    cells = [("vertex", np.arange(len(x), dtype=np.int64).reshape(-1, 1))]
    meshio.write(path, meshio.Mesh(pts, cells, point_data=data), file_format="vtu")
