"""Figures a reader can trust (pardem.io.figures, the plot modules): a run stopped by --steps says
so on its figures; grains are drawn at their size; coinciding curves are told apart."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SMALL = os.path.join(ROOT, "drivers", "isotropic_small.toml")
plt = pytest.importorskip("matplotlib.pyplot")


def description(path):
    from PIL import Image
    with Image.open(path) as im:
        return im.info.get("Description")


def red_share(path, rows=slice(0, 12)):
    """The share of firebrick pixels in the top rows of a PNG (the banner's colour)."""
    img = plt.imread(path)[rows, :, :3]
    return np.mean(np.all(np.abs(img - np.array([178, 34, 34]) / 255.0) < 0.03, axis=-1))


def iso_run(out, *extra):
    cmd = [sys.executable, "-m", "pardem.drivers.isotropic", "--config", SMALL, "--set", "sample.n=60",
           "--set", 'preparation.relaxation="fire"', "--pressures", "1e6", "--quiet", "--out", str(out), *map(str, extra)]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]


def test_a_truncated_run_says_so_on_its_figures(tmp_path):
    iso_run(tmp_path / "short", "--steps", 600)
    s = json.loads((tmp_path / "short" / "isotropic.json").read_text())
    assert not s["finished"] and s["steps"] >= 600
    png = tmp_path / "short" / "isotropic.png"
    note = description(png)
    assert note is not None and "TRUNCATED" in note and str(s["steps"]) in note
    assert red_share(png) > 0.05


def test_a_whole_run_is_not_marked(tmp_path):
    iso_run(tmp_path / "whole")
    png = tmp_path / "whole" / "isotropic.png"
    assert description(png) is None and red_share(png) < 0.01


def test_compress_plot_marks_a_truncated_summary(tmp_path):
    from pardem.io.compress_plot import plot
    t = np.linspace(0.0, 1.0, 20)
    series = {"time": t, "eps_xx": -1e-3 * t, "eps_yy": 0 * t, "eps_zz": 0 * t,
              "force_fixed": 1e3 * t, "force_moving": 1e3 * t}
    base = {"loading_axis": "x", "cross_section": 1e-4, "young_modulus": 1e9, "n_ranks": 1}
    plot(series, {**base, "finished": True}, tmp_path / "whole.png")
    plot(series, {**base, "finished": False, "steps": 300, "stopped": "stopped at --steps 300"},
         tmp_path / "short.png")
    assert description(tmp_path / "whole.png") is None
    assert "stopped at --steps 300" in description(tmp_path / "short.png")
    assert red_share(tmp_path / "short.png", slice(0, 20)) > 0.05 > red_share(tmp_path / "whole.png", slice(0, 20))


def test_grains_are_drawn_at_their_size():
    """Disks of known radii on 10 mm x 10 mm axes of 500 x 500 pixels: the covered pixels are
    the disks' area (pi sum r^2) to within their rim (one pixel around each: 2 pi r / 50 mm^2 of
    area per pixel width, ~3 % here)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from pardem.io.biaxial_plot import grain_disks
    x = np.array([[2.0, 2.0], [6.0, 3.0], [4.0, 7.5]])          # mm
    r = np.array([1.5, 1.0, 2.0])
    fig = Figure(figsize=(5, 5), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes([0, 0, 1, 1])
    grain_disks(ax, x, 2 * r, np.ones(3), "Greys", 0.0, 1.0, linewidths=0)
    ax.set_xlim(0, 10)
    ax.set_ylim(0, 10)
    ax.set_aspect("equal")
    ax.axis("off")
    canvas.draw()
    img = np.asarray(canvas.buffer_rgba())[..., :3]
    covered = np.mean(np.all(img < 128, axis=-1)) * 100.0        # mm^2
    rim = 2 * np.pi * r.sum() * (10.0 / 500)                      # one pixel around every disk
    assert covered == pytest.approx(np.pi * np.sum(r**2), abs=rim)


def test_coinciding_curves_are_named_and_drawn_apart(tmp_path):
    from types import SimpleNamespace
    from pardem.io.anisotropy_plot import LAW_STYLES, coinciding, plot_study
    x = np.array([1.0, 2.0, 4.0])
    y = np.array([1.0, 1.8, np.nan])
    curves = {"TOR": (x, y), "hankinson": (x, y * (1 + 1e-12)), "linear": (x, y + 1e-3),
              "spherical": (x, y.copy())}
    assert coinciding(curves) == [["TOR", "hankinson", "spherical"]]
    assert coinciding({"a": (x, y), "b": (x[:2], y[:2])}) == []
    assert coinciding({"a": (x, y), "b": (x + 1.0, y)}) == []
    # every law its own marker and dash, the markers nested by size
    styles = list(LAW_STYLES.values())
    assert len({m for m, _, _ in styles}) == len({str(d) for _, _, d in styles}) == len(styles)
    assert [s for _, s, _ in styles] == sorted((s for _, s, _ in styles), reverse=True)
    rows = [{"bond_LR": b, "LR_mean": 0.9 * b, "LR_std": 0.0, "bond_LT": b, "LT_mean": 0.8 * b, "LT_std": 0.0}
            for b in (1.0, 2.0, 4.0)]
    laws = ("TOR", "hankinson", "linear", "spherical")
    plan = SimpleNamespace(kinds=("ordered",), laws=laws, offaxis_ratio=2.0)
    plot_study({"ordered": {law: rows for law in laws}}, plan, tmp_path / "a.png")
    assert (tmp_path / "a.png").stat().st_size > 1000


def test_localisation_maps_draw_every_grain_as_a_disk(tmp_path, monkeypatch):
    from pardem.io import biaxial_plot
    drawn = []
    real = biaxial_plot.grain_disks

    def spy(ax, x, diameter, *args, **kw):
        drawn.append((np.array(x), np.array(diameter)))
        return real(ax, x, diameter, *args, **kw)

    monkeypatch.setattr(biaxial_plot, "grain_disks", spy)
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 1e-2, (30, 2))
    radius = rng.uniform(1e-4, 3e-4, 30)
    field = {"x": x, "shear": rng.uniform(0, 1e-2, 30), "spin": rng.normal(size=30) * 1e-3,
             "band": {"centre": [5e-3, 5e-3], "direction": [0.6, 0.8], "angle_deg": 53.1, "width_d": 4.0}}
    assert biaxial_plot.maps(tmp_path / "m.png", field, radius, "window")
    assert len(drawn) == 2                       # both panels
    for centres, d in drawn:
        np.testing.assert_array_equal(centres, x * 1e3)
        np.testing.assert_array_equal(d, 2e3 * radius)   # diameters in the axes' mm
