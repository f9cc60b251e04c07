"""The direct shear box (``pardem.protocols.direct_shear``, driver ``direct_shear``) on its short deck
(``drivers/direct_shear_short.toml``: 1000 spheres, mu_p = 0.5, sigma_n = 10 kPa; the restart on
300 spheres and a shorter shear): the lid's servo,
the dilatancy of a dense sample, the friction it measures against frictionless grains, a restart
equal to the uninterrupted run, one clear error for a bad deck."""
import glob
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from pardem.drivers import direct_shear as driver
from pardem.io.deck_file import load_deck
from pardem.io.series import read_series
from pardem.protocols import direct_shear as ds

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHORT = os.path.join(ROOT, "drivers", "direct_shear_short.toml")
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
SIGMA = 1e4          # shear.normal_stress of the deck [Pa]


def run(out, *extra):
    code = driver.main(["--config", SHORT, "--out", str(out), "--quiet", *extra])
    return code


def rows(out):
    return read_series(os.path.join(str(out), "direct_shear.csv"), columns=None)


def summary(out):
    import json
    with open(os.path.join(str(out), "direct_shear.json")) as f:
        return json.load(f)


def final_state(out):
    """Positions, velocities, spins by gid of the last checkpoint, and its step."""
    path = max(glob.glob(os.path.join(str(out), "checkpoints", "checkpoint-*.h5")),
               key=lambda p: int(p.rsplit("-", 1)[1].split(".")[0]))
    with h5py.File(path, "r") as f:
        o = np.argsort(f["elements/gid"][...])
        return {k: f["elements/" + k][...][o] for k in ("x", "v", "w")}, int(f.attrs["step"])


@pytest.fixture(scope="module")
def sheared(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "full"
    assert run(out) == 0
    return out


def test_servo_holds_the_normal_stress(sheared):
    s = rows(sheared)
    sig = np.asarray(s["sigma_n"])
    # the preparation ends at rest (kinetic energy ~1e-10 J): the servo's fixed point is its target,
    # up to the residual motion: 1 %
    assert abs(sig[0] / SIGMA - 1.0) < 0.01, sig[0]
    # during the shear the lid rises with the dilation at v_lid; the servo's law v = gain (F_t - F)
    # needs the force error F_t - F = -v_lid / gain to do so: sigma / sigma_n - 1 = v_lid / (gain F_t)
    # (about 1 % at the deck's gain). The measured stress follows it to 2 % on average (the force
    # chains under the lid rearrange between samples); it stays within 10 % throughout
    deck = load_deck(ds.SCHEMA, SHORT, [])
    L = deck["sample"]["box"] * deck["sample"]["radius"]
    target = SIGMA * L * L
    t, dz = np.asarray(s["time"]), np.asarray(s["dilation"])
    v_lid = np.diff(dz) / np.diff(t)
    lag = v_lid / (ds.servo_gain(deck) * target)
    mid = 0.5 * (sig[1:] + sig[:-1]) / SIGMA - 1.0
    on = np.asarray(s["displacement"])[1:] >= 0.02 * L
    assert np.abs(mid[on] - lag[on]).mean() < 0.02, (np.abs(mid[on] - lag[on]).mean(), np.abs(mid[on]).mean())
    assert np.abs(mid[on]).max() < 0.1


def test_dense_sample_dilates_and_softens(sheared):
    sm = summary(sheared)
    # a dense sample (prepared with frictionless grains) dilates at the peak and softens after it
    # (Bolton, Geotechnique 36, 65 (1986); Cui & O'Sullivan, Geotechnique 56, 455 (2006), DEM
    # spheres in the shear box)
    assert sm["dilation_at_peak"] > 0.0
    assert sm["final_dilation"] > 0.0
    assert sm["peak_friction"] > sm["residual_friction"]


def test_residual_friction_of_frictional_spheres(sheared, tmp_path):
    # spheres of mu_p = 0.5 shear steadily at a macroscopic friction of 0.35-0.45 (GDR MiDi, Eur.
    # Phys. J. E 14, 341 (2004); da Cruz et al., Phys. Rev. E 72, 021309 (2005)), frictionless
    # spheres at ~0.1 (Peyneau & Roux, Phys. Rev. E 78, 011307 (2008)): a difference of 0.25-0.35.
    # This small box (10 grains across, walls of zero thickness meeting at the shear plane) adds
    # its edges' resistance to both (about 0.1-0.2, see the report), so the assertions are the
    # lower bound of the literature's range and the difference between the two grain frictions
    out = tmp_path / "mu0"
    assert run(out, "--set", "contacts.friction=0.0") == 0
    frictionless = summary(out)["residual_friction"]
    frictional = summary(sheared)["residual_friction"]
    assert frictional > 0.3, frictional
    assert frictional - frictionless > 0.2, (frictional, frictionless)
    assert frictionless > 0.0


SMALL = ("--set", "sample.n=300", "--set", "sample.box=12.0", "--set", "preparation.steps=8000",
         "--set", "shear.displacement=0.05")


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The small case (300 spheres, a short shear) run through on 1 rank."""
    out = tmp_path_factory.mktemp("ds") / "whole"
    assert run(out, *SMALL) == 0
    return out


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_two_ranks_same_state(whole, tmp_path):
    # each grain's wall and contact loads depend on that grain and its neighbours alone, the servo
    # reads an exact sum: the trajectory is the same bits on 2 ranks (engine/walls.py); the series'
    # wall forces are floating-point sums over rows then ranks, equal to about n eps sum_k |F_k|
    # (n ~ 300 rows, eps = 2.2e-16: 7e-14 of the sum of magnitudes, which exceeds the net force by
    # at most a factor ~1e3 here): rtol 1e-9
    out = tmp_path / "two"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.direct_shear", "--config", SHORT,
                        *SMALL, "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    a, sa = final_state(out)
    b, sb = final_state(whole)
    assert sa == sb
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    ra, rb = rows(out), rows(whole)
    for c in ("shear_force", "normal_force"):
        x, y = np.asarray(ra[c]), np.asarray(rb[c])
        assert np.allclose(x, y, rtol=1e-9, atol=1e-12 * np.abs(y).max()), c


def test_restart_equals_uninterrupted_run(whole, tmp_path):
    small = SMALL
    first, second = tmp_path / "a", tmp_path / "b"
    stop = 8000 + 700          # inside the shear (preparation.steps = 8000)
    assert run(first, *small, "--steps", str(stop)) == 0
    state, step = final_state(first)
    assert step == stop
    ck = glob.glob(os.path.join(str(first), "checkpoints", f"checkpoint-*{stop}.h5"))
    assert len(ck) == 1
    assert driver.main(["--restart", ck[0], "--out", str(second), "--quiet"]) == 0
    a, sa = final_state(second)
    b, sb = final_state(whole)
    assert sa == sb
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    ra, rb = rows(second), rows(whole)
    for c in ("step", "shear_force", "normal_force", "dilation"):
        assert np.array_equal(np.asarray(ra[c]), np.asarray(rb[c])), c


def test_bad_deck_is_one_error(tmp_path, capsys):
    # 300 spheres of R (1 +- 0.2) do not fit a gas at a solid fraction of 0.35 by random addition
    with pytest.raises(SystemExit) as stop:
        run(tmp_path / "bad", "--set", "sample.gas_fraction=0.35")
    assert stop.value.code == 2
    assert not (tmp_path / "bad").exists()      # refused before any output
    assert "sample.gas_fraction" in capsys.readouterr().err
