"""Files of the point-load response driver: the figure ``response.png`` and the ParaView snapshots
of the perturbation (``response_vtk/response.pvd``). Rank 0 only (the protocol gathers the data).

``plot(path, result)``: four panels (needs matplotlib; a note on stderr and no file otherwise):
(a) the static profiles ``-dsigma_yy / (F / (t z))`` against ``x / z`` at a few depths, with
Flamant's ``2 / (pi (1 + x^2/z^2)^2)`` (the same scaled form at every depth); (b) the profile half
width at half maximum against depth with Flamant's ``0.6436 z``, the layer on a rigid base, the
diffusive fit ``sqrt(2 D z)`` and the static linear response's widths (``static.linear``); (c) the transmitted force ``-t sum dsigma_yy dx / F`` per layer;
(d) the dynamic profiles at the layer closest to mid-depth, one line per snapshot time.

``PerturbationVTK(directory)``: one VTK XML unstructured grid per record (``response-KKK.vtu``,
points = grain centres, vertex cells) with the point arrays ``radius`` [m], ``dsigma_yy`` [Pa]
(per-grain stress change, ``pardem.protocols.response.per_grain_stress``), ``dM_yy`` [N m],
``displacement`` [m] (3 components, from the reference state), ``gid``, and a ``response.pvd``
collection (``timestep`` = simulation time [s]; the static state last). Open ``response.pvd`` in
ParaView, Glyph > Sphere scaled by ``radius``, colour by ``dsigma_yy``.
"""
import os

import meshio
import numpy as np

from pardem.io.figures import pyplot


def plot(path, result):
    """Draw ``response.png`` from the response driver's ``result`` (the summary's fields)."""
    plt = pyplot("response.png")
    if plt is None:
        return
    st = result["static"]
    F, t = result["force"], result["geometry"]["thickness"]
    d = result["geometry"]["mean_diameter"]
    x = np.asarray(st["x"])
    z = np.asarray(st["depth"])
    s = np.asarray(st["dsigma_yy"])
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    a = ax[0, 0]
    picks = sorted(set(np.linspace(0, len(z) - 1, min(4, len(z))).round().astype(int)))
    for k in picks:
        a.plot(x / z[k], -s[k] * t * z[k] / F, "o-", ms=3, label=f"z = {z[k] / d:.1f} d")
    u = np.linspace(-4, 4, 400)
    a.plot(u, 2.0 / (np.pi * (1 + u * u) ** 2), "k--", label="Flamant")
    a.set_xlim(-4, 4)
    a.set_xlabel("x / z [-]")
    a.set_ylabel("-dsigma_yy t z / F [-]")
    a.set_title("static response profiles")
    a.legend(fontsize=8)
    a = ax[0, 1]
    hw = [np.nan if w is None else w for w in st["width_half_max"]]
    a.plot(z / d, np.asarray(hw) / d, "o", label="packing (half width at half max)")
    fw = [np.nan if w is None else w for w in st["flamant"]["width_half_max"]]
    a.plot(z / d, np.asarray(fw) / d, "k--", label="Flamant (binned)")
    lw = [np.nan if w is None else w for w in st["layer_on_rigid_base"]["width_half_max"]]
    a.plot(z / d, np.asarray(lw) / d, "b:", label="layer on rigid base")
    lin = st.get("linear")
    if lin is not None:
        nz = min(len(z), len(lin["width_half_max"]))
        lh = [np.nan if w is None else w for w in lin["width_half_max"][:nz]]
        a.plot(z[:nz] / d, np.asarray(lh) / d, "gs", mfc="none", label="static linear (no sliding, no opening)")
    D = st["fits_half_max"]["D"]
    if D:
        a.plot(z / d, np.sqrt(2 * D * z) / d, "r-.", label=f"diffusive sqrt(2 D z), D = {D / d:.3g} d")
    a.set_xlabel("depth z [mean diameters]")
    a.set_ylabel("width [mean diameters]")
    a.set_title("profile width")
    a.legend(fontsize=8)
    a = ax[1, 0]
    a.plot(z / d, st["transmitted_over_F"], "o-", label="relaxed")
    if lin is not None:
        a.plot(z[:nz] / d, lin["transmitted_over_F"][:nz], "gs", mfc="none", label="static linear")
        a.legend(fontsize=8)
    a.axhline(1.0, color="k", ls="--", lw=0.8)
    a.set_xlabel("depth z [mean diameters]")
    a.set_ylabel("-t sum dsigma_yy dx / F [-]")
    a.set_title("force transmitted through each layer")
    a = ax[1, 1]
    if result["dynamic"]:
        k = int(np.argmin(np.abs(z - 0.5 * z.max())))
        for r in result["dynamic"]:
            a.plot(x / d, -np.asarray(r["dsigma_yy"])[k] * t / F * d, label=f"t = {r['time_over_transit']:g} H/c")
        a.plot(x / d, -s[k] * t / F * d, "k-", lw=2, label="static")
        a.set_title(f"dynamic response at z = {z[k] / d:.1f} d")
        a.legend(fontsize=8)
    a.set_xlabel("x [mean diameters]")
    a.set_ylabel("-dsigma_yy t d / F [-]")
    for a in ax.ravel():
        a.grid(alpha=0.3)
    k = st.get("points", 1)
    fig.suptitle(f"point-load response: F = {F:.3g} N, {result['geometry']['n_grains']} grains, "
                 f"t = {t:.3g} m (stress per unit area / t)"
                 + (f"; static: mean over {k} load points, dynamic: the first" if k > 1 else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


class PerturbationVTK:
    """Rank 0's writer of the perturbation snapshots (module docstring) into ``directory``.

    ``entries``: the ``(time [s], absolute path)`` of the snapshots an interrupted run wrote
    (``self.entries`` of its writer, kept in its checkpoint): a restart, written into another
    folder, continues their numbering and its ``response.pvd`` lists them too (relative paths)."""

    def __init__(self, directory, entries=()):
        self.directory = os.path.abspath(directory)
        os.makedirs(self.directory, exist_ok=True)
        self.entries = [(float(t), str(p)) for t, p in entries]

    def write(self, time, x, radius, dsigma_yy, dM_yy, displacement, gid):
        k = len(self.entries)
        name = f"response-{k:03d}.vtu"
        pts = np.ascontiguousarray(x, dtype=np.float64)
        mesh = meshio.Mesh(pts, [("vertex", np.arange(len(pts)).reshape(-1, 1))],
                           point_data={"radius": np.asarray(radius, dtype=np.float64),
                                       "dsigma_yy": np.asarray(dsigma_yy, dtype=np.float64),
                                       "dM_yy": np.asarray(dM_yy, dtype=np.float64),
                                       "displacement": np.ascontiguousarray(displacement, dtype=np.float64),
                                       "gid": np.asarray(gid, dtype=np.int64)})
        path = os.path.join(self.directory, name)
        meshio.write(path, mesh, file_format="vtu")
        self.entries.append((float(time), path))
        self._pvd()
        return name

    def _pvd(self):
        lines = ['<?xml version="1.0"?>', '<VTKFile type="Collection" version="0.1">', "  <Collection>"]
        for t, path in self.entries:
            lines.append(f'    <DataSet timestep="{t:.9e}" group="" part="0" '
                         f'file="{os.path.relpath(path, self.directory)}"/>')
        lines += ["  </Collection>", "</VTKFile>", ""]
        path = os.path.join(self.directory, "response.pvd")
        with open(path + ".tmp", "w") as fh:
            fh.write("\n".join(lines))
        os.replace(path + ".tmp", path)


__all__ = ["plot", "PerturbationVTK"]
