"""Figures and field files of the 2D biaxial test (``pardem.protocols.biaxial``), rank 0 only.

* ``curves(path, rows)``: deviator q / pc and volumetric strain against axial strain, one line per
  confining pressure (PNG, labelled axes and units); for cemented samples a third panel: the
  broken-cement count and broken fraction against axial strain;
* ``cement_map(path, x, radius, ends, strain, title, band)``: the broken cements of a loading as
  segments between the pair's centres, coloured by the axial strain at which they broke, over the
  grains (drawn as disks) at the end of the loading, with the last window's band centre line;
* ``write_cement_fields(path, x, gid, radius, broken, intact, pairs, strain)``: the same as a VTU
  (grains as points with ``radius``, ``gid``, ``cements_broken``, ``cements_intact``; the broken
  cements as lines with cell data ``break_strain``, -1 on the grains' vertex cells);
* ``maps(path, field, title)``: the incremental shear strain and the grains' rotation increments of
  a localisation window, each grain a disk of its own size (``grain_disks``), with the detected
  band's centre line;
* ``write_fields(path, field, gid, radius)``: the same fields as a VTK XML unstructured grid of points
  (``radius``, ``gid``, ``shear``, ``volumetric``, ``rotation``, ``spin``, ``platen``,
  ``cements_broken`` point data) for ParaView:
  open it, then Glyph (Sphere, scale by radius) and colour by ``shear``.

matplotlib is optional: without it the PNGs are skipped with a note (``False`` returned).
"""
import numpy as np

from pardem.io.figures import pyplot


def curves(path, rows):
    """q / pc and eps_v [%] against eps_a [%] per confining pressure (``rows``: the series)."""
    plt = pyplot("biaxial figures")
    if plt is None or not rows:
        return False
    cemented = any(r.get("cements_intact", 0) + r.get("cements_broken", 0) > 0 for r in rows)
    fig, ax = plt.subplots(3 if cemented else 2, 1, figsize=(6, 10 if cemented else 7), sharex=True)
    right = ax[2].twinx() if cemented else None
    for k in sorted({int(r["pressure_index"]) for r in rows}):
        rs = [r for r in rows if int(r["pressure_index"]) == k]
        ea = [100.0 * r["eps_axial"] for r in rs]
        pc = rs[0]["pc"]
        line = ax[0].plot(ea, [r["q"] / pc for r in rs], label=f"pc = {pc:.3g} Pa")[0]
        ax[1].plot(ea, [100.0 * r["eps_vol"] for r in rs], label=f"pc = {pc:.3g} Pa")
        if cemented:
            ax[2].plot(ea, [r["cements_broken"] for r in rs], color=line.get_color(), label=f"pc = {pc:.3g} Pa")
            right.plot(ea, [100.0 * r["broken_fraction"] for r in rs], color=line.get_color(), ls=":")
    ax[0].set_ylabel("deviator q / pc [-]")
    ax[1].set_ylabel("volumetric strain eps_v [%] (contraction +)")
    if cemented:
        ax[2].set_ylabel("broken cements [-] (solid)")
        right.set_ylabel("broken fraction [%] (dotted)")
        right.set_ylim(bottom=0.0)
        ax[2].set_ylim(bottom=0.0)
    ax[-1].set_xlabel("axial strain eps_a [%]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    ax[0].set_title("2D biaxial test, flexible membranes" + (", cemented" if cemented else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def grain_disks(ax, x, diameter, values=None, cmap=None, vmin=None, vmax=None, **style):
    """Add to ``ax`` one disk per grain at its size in data units: centres ``x`` [n, 2] and
    ``diameter`` [n] in the axes' units (an ``EllipseCollection``, ``units="xy"``: the disks
    scale with the axes, set an equal aspect), coloured by ``values`` [n] (or ``style``'s
    ``facecolors``). Returns the collection (a mappable for ``colorbar``)."""
    from matplotlib.collections import EllipseCollection
    d = np.asarray(diameter, dtype=float)
    disks = EllipseCollection(d, d, np.zeros(len(d)), units="xy", offsets=np.asarray(x, dtype=float),
                              offset_transform=ax.transData, **style)
    if values is not None:
        disks.set_array(np.asarray(values, dtype=float))
        disks.set_cmap(cmap)
        disks.set_clim(vmin, vmax)
    ax.add_collection(disks)
    return disks


def maps(path, field, radius, title=""):
    """Incremental shear strain [-] and grain rotation increment [rad] of a window, each grain a
    disk of its radius ``radius`` [n] [m] at its centre ``field["x"]`` [m] (drawn in mm)."""
    plt = pyplot("biaxial figures")
    if plt is None:
        return False
    x = np.asarray(field["x"]) * 1e3
    d = 2e3 * np.asarray(radius, dtype=float)
    fig, ax = plt.subplots(1, 2, figsize=(11, 5.5))
    shear = np.where(np.isfinite(field["shear"]), field["shear"], 0.0)
    a = grain_disks(ax[0], x, d, shear, "viridis", 0.0, float(np.quantile(shear, 0.98)) or None)
    fig.colorbar(a, ax=ax[0], label="incremental shear strain [-]")
    spin = np.asarray(field["spin"])
    lim = float(np.quantile(np.abs(spin), 0.98)) or 1e-12
    b = grain_disks(ax[1], x, d, spin, "coolwarm", -lim, lim)
    fig.colorbar(b, ax=ax[1], label="grain rotation increment [rad] (counter-clockwise +)")
    band = field.get("band")
    pad = float(d.max()) if len(d) else 0.0
    for axis in ax:
        if band is not None:
            c, u = np.asarray(band["centre"]) * 1e3, np.asarray(band["direction"])
            span = np.ptp(x, axis=0).max()
            axis.plot([c[0] - span * u[0], c[0] + span * u[0]], [c[1] - span * u[1], c[1] + span * u[1]],
                      "k--", lw=0.8)
        axis.set_xlim(x[:, 0].min() - pad, x[:, 0].max() + pad)
        axis.set_ylim(x[:, 1].min() - pad, x[:, 1].max() + pad)
        axis.set_aspect("equal")
        axis.set_xlabel("x [mm]")
        axis.set_ylabel("y [mm]")
    if band is None:
        what = ""
    elif band.get("localised", True):
        what = f"; band at {band['angle_deg']:.1f} deg, width {band['width_d']:.1f} d"
    else:
        what = f"; not localised (best line dashed, contrast {band['contrast']:.2f})"
    fig.suptitle(title + what + "\ngrains drawn at their size")
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


def cement_map(path, x, radius, ends, strain, title="", band=None):
    """Broken cements over the grains at the end of a loading: grains at ``x`` [n, 2] [m] of
    ``radius`` [n] [m] as grey disks, each broken cement a segment between its pair's centres
    ``ends`` [m, 2, 2] [m], coloured by the axial strain at which it broke ``strain`` [m] (drawn
    in mm and %); ``band``: a shear band (``centre``, ``direction``) drawn as a dashed line."""
    plt = pyplot("biaxial figures")
    if plt is None:
        return False
    from matplotlib.collections import LineCollection
    x = np.asarray(x, dtype=float) * 1e3
    d = 2e3 * np.asarray(radius, dtype=float)
    fig, ax = plt.subplots(figsize=(7, 7))
    grain_disks(ax, x, d, facecolors="0.88", edgecolors="0.6", linewidths=0.3)
    ends = np.asarray(ends, dtype=float).reshape(-1, 2, 2) * 1e3
    strain = 100.0 * np.asarray(strain, dtype=float)
    if len(ends):
        lc = LineCollection(ends, array=strain, cmap="plasma", linewidths=1.8)
        lc.set_clim(0.0, max(float(strain.max()), 1e-12))
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, shrink=0.8, label="axial strain at rupture eps_a [%]")
    if band is not None:
        c, u = np.asarray(band["centre"]) * 1e3, np.asarray(band["direction"])
        span = np.ptp(x, axis=0).max()
        ax.plot([c[0] - span * u[0], c[0] + span * u[0]], [c[1] - span * u[1], c[1] + span * u[1]], "k--", lw=0.8,
                label=f"shear band ({band['angle_deg']:.1f} deg)")
        ax.legend(fontsize=8, loc="upper right")
    pad = float(d.max()) if len(d) else 0.0
    ax.set_xlim(x[:, 0].min() - pad, x[:, 0].max() + pad)
    ax.set_ylim(x[:, 1].min() - pad, x[:, 1].max() + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return True


def write_cement_fields(path, x, gid, radius, broken, intact, pairs, strain):
    """Grains [n] as points (``x`` [n, 2] [m]; point data ``radius`` [m], ``gid``,
    ``cements_broken`` and ``cements_intact`` per grain) and the broken cements as lines between
    the rows ``pairs`` [m, 2] of their two grains (cell data ``break_strain``: the axial strain at
    rupture; -1 on the grains' vertex cells)."""
    import meshio
    x = np.asarray(x, dtype=np.float64)
    pts = np.column_stack([x, np.zeros(len(x))])
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    data = {"radius": np.asarray(radius, dtype=np.float64), "gid": np.asarray(gid, dtype=np.int64),
            "cements_broken": np.asarray(broken, dtype=np.int32), "cements_intact": np.asarray(intact, dtype=np.int32)}
    cells = [("vertex", np.arange(len(x), dtype=np.int64).reshape(-1, 1))]
    cell_data = [np.full(len(x), -1.0)]
    if len(pairs):
        cells.append(("line", pairs))
        cell_data.append(np.asarray(strain, dtype=np.float64))
    meshio.write(path, meshio.Mesh(pts, cells, point_data=data, cell_data={"break_strain": cell_data}),
                 file_format="vtu")
