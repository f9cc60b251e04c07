"""Point-load response of a 2D packing (issue 13 item 4): ``pardem.physics.flamant``,
``pardem.physics.response``, ``pardem.engine.replicate``, ``pardem.protocols.response`` and the
driver ``python -m pardem.drivers.response``.

Oracles:
* Flamant's half-plane solution against an independent numerical quadrature (scipy ``quad``): at
  every depth ``int sigma_zz dx = -F / t``, and the exact bin averages equal the quadrature over
  each bin; the Fourier-series layer on a rigid base equals Flamant's closed form with periodic
  images when the layer is much thicker than the period (the bottom's effect is ``exp(-2 pi H / L)``);
* force balance (the exact statement derived in ``pardem.physics.response``): on a triangular
  lattice, whose reference contact points lie on the faces of bands centred on its rows,
  ``-sum_band dM_yy / h = F`` at every depth below the load, up to the relaxations' unbalanced
  forces (bound computed from them);
* linearity: the response to 2F is twice the response to F, within the Hertz nonlinearity bound;
* the same run on 1 and 2 ranks (bit for bit: the engine's sums are exact);
* replication: every copy of a frictional packing with tangential history has the original's
  contact forces pair by pair, and keeps the original's dynamics (forces after a few steps);
* the driver on 2 ranks: outputs, the rows' shares of the load (sum 1), the per-layer force.
"""
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from scipy.integrate import quad

from pardem.engine.replicate import replicate
from pardem.parallel.communicator import Communicator
from pardem.physics import flamant as fl
from pardem.physics import response as rsp
from pardem.protocols import response

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests", "mpi"))
import response_run  # noqa: E402
from _util import granular_case

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
SHORT = os.path.join(ROOT, "drivers", "response_short.toml")


# -- Flamant and the layer ------------------------------------------------------------------------

@pytest.mark.parametrize("z", [0.3, 1.0, 4.0])
def test_flamant_integrates_to_the_load_at_every_depth(z):
    F, t = 2.0, 0.5
    val, err = quad(lambda x: float(fl.flamant_sigma_zz(x, z, F, t)), -np.inf, np.inf, epsabs=1e-13, epsrel=1e-12)
    assert val == pytest.approx(-F / t, rel=1e-9)          # quad's own error estimate is ~1e-12
    # the exact bin averages against quadrature over each bin
    edges = np.linspace(-3.0, 3.0, 7)
    avg = fl.flamant_bin_average(edges, [z], F, t)[0]
    for k in range(6):
        q = quad(lambda x: float(fl.flamant_sigma_zz(x, z, F, t)), edges[k], edges[k + 1], epsrel=1e-12)[0]
        assert avg[k] == pytest.approx(q / (edges[k + 1] - edges[k]), rel=1e-9)
    # the profile's second-moment width is z and its half width at half maximum 0.6436 z
    m2 = quad(lambda x: x * x * float(fl.flamant_sigma_zz(x, z, F, t)), -np.inf, np.inf, epsrel=1e-12)[0]
    assert math.sqrt(m2 / val) == pytest.approx(z, rel=1e-8)
    s0 = float(fl.flamant_sigma_zz(0.0, z, F, t))
    assert float(fl.flamant_sigma_zz(fl.HWHM_FACTOR * z, z, F, t)) == pytest.approx(0.5 * s0, rel=1e-12)


def test_thick_layer_is_flamant_with_images_and_integrates_to_the_load():
    L, H = 20.0, 100.0          # exp(-2 pi H / L) = 2e-14: the bottom does not matter
    x = np.linspace(-10.0, 10.0, 41)
    z = np.array([1.0, 3.0, 8.0])
    layer = fl.layer_sigma_zz(x, z, 1.0, 1.0, H, L, 0.3)
    images = fl.flamant_sigma_zz(x[None, :], z[:, None], 1.0, 1.0, period=L, images=4000)
    # images beyond |m| = 4000: sum 2 * 2 z^3 / (pi (m L)^4) < 1e-12 of the peak
    assert np.max(np.abs(layer - images)) < 1e-6 * np.max(np.abs(images))
    # a thin layer: the rigid base concentrates the load (a stiffer support), and every depth
    # still carries the load (the n = 0 mode); quadrature of the periodic series over one period
    thin = fl.layer_sigma_zz(x, [8.0], 1.0, 1.0, 10.0, L, 0.3)[0]
    assert thin[20] < images[2, 20]
    xs = np.linspace(-10.0, 10.0, 2001)[:-1]
    prof = fl.layer_sigma_zz(xs, [8.0], 1.0, 1.0, 10.0, L, 0.3)[0]
    assert prof.mean() * L == pytest.approx(-1.0, rel=1e-9)   # the rectangle rule is exact for a
    # trigonometric polynomial of degree below the number of points


def test_widths_and_fits():
    z = np.array([1.0, 2.0, 4.0, 8.0])
    x = np.linspace(-200, 200, 40001)
    hw = [rsp.widths(x, -fl.flamant_sigma_zz(x, zz, 1.0, 1.0))[1] for zz in z]
    assert np.allclose(hw, fl.HWHM_FACTOR * z, rtol=1e-4)      # linear interpolation on a 0.01 grid
    fits = rsp.fit_widths(z, np.sqrt(2 * 0.7 * z))
    assert fits["D"] == pytest.approx(0.7, rel=1e-12) and fits["diffusive_residual"] < 1e-12


# -- the response of a lattice ---------------------------------------------------------------------

def _row_sums(dM, y, h):
    rows = np.round(y / h - 0.5).astype(int)
    return np.array([dM[rows == k].sum() for k in range(1, rows.max())]), rows


def _residual_bound(meta):
    """|(-sum_band dM_yy / h) / F - 1| <= sum over the grains of |dR_y| / F <= N (u_ref + u_static)
    <f_c> / F (``unbalanced`` = mean |R| / mean |f_c|); plus round-off."""
    return meta["n"] * (meta["u_ref"] + meta["u_static"]) * meta["mean_contact_force"] / meta["force"] + 1e-9


@pytest.fixture(scope="module")
def lattice_runs():
    comm = Communicator()
    out = {}
    for frac in (0.01, 0.02):
        res, layer, h = response_run.run(comm, fraction=frac)
        pg = res.pop("_per_grain")
        out[frac] = {"dM": pg["dM_yy"], "y": layer.geometry["y"], "h": h, "res": res,
                     "meta": {"n": layer.geometry["n_grains"], "u_ref": res["reference"]["unbalanced"],
                              "u_static": res["static"]["unbalanced"], "force": res["force"],
                              "mean_contact_force": res["reference"]["mean_contact_force"]}}
    return out


def test_lattice_response_integrates_to_the_load_at_every_depth(lattice_runs):
    r = lattice_runs[0.01]
    sums, rows = _row_sums(r["dM"], r["y"], r["h"])
    F = r["meta"]["force"]
    bound = _residual_bound(r["meta"])
    # the bands of rows 1 .. 10 (row 0 is the clamped base, row 11 the free top with the load)
    assert len(sums) == 10
    assert np.all(np.abs(-sums / r["h"] / F - 1.0) <= bound), (-sums / r["h"] / F, bound)
    assert r["res"]["reactions"]["bottom_share"] == pytest.approx(1.0, abs=bound)
    assert r["res"]["reactions"]["top_share"] == 0.0     # dead loads: the top row takes nothing
    assert r["res"]["static"]["converged"] and bound < 1e-4
    # the binned profile: a layer of height H_l holding m rows (its grains' dM summed over the x
    # bins) gives -t sum dsigma dx / F = m h / H_l (the deck's layers are one diameter, rows 0.866 d
    # apart: aliasing, 1 or 2 rows per layer); so m must come out an integer, within the bound
    st = r["res"]["static"]
    tr = np.asarray(st["transmitted_over_F"])
    H_l = st["z_edges"][1] - st["z_edges"][0]
    m = tr * H_l / r["h"]
    assert np.all(np.abs(m - np.round(m)) <= bound * np.round(m)) and set(np.round(m)) <= {1.0, 2.0}


def test_lattice_response_is_linear(lattice_runs):
    a, b = lattice_runs[0.01], lattice_runs[0.02]
    sa = np.asarray(a["res"]["static"]["dsigma_yy"])
    sb = np.asarray(b["res"]["static"]["dsigma_yy"])
    # Hertz f ~ delta^(3/2): the quadratic part of a contact's response over its linear part is
    # (1/6) df/f; the largest df/f is at the loaded grain's two lower contacts, F / (2 cos 30 deg)
    # over the mean contact force; response(2F) - 2 response(F) = 2 x the quadratic part of F;
    # plus the relaxations' residuals (both runs)
    eps = a["meta"]["force"] / (2 * math.cos(math.pi / 6)) / a["meta"]["mean_contact_force"]
    tol = 2 * eps / 6 + _residual_bound(a["meta"]) + _residual_bound(b["meta"])
    dev = np.max(np.abs(sb - 2 * sa)) / np.max(np.abs(2 * sa))
    assert dev < tol, (dev, tol)
    assert np.max(np.abs(sb - 2 * sa)) > 0.0      # the law is not linear: the runs are distinct


def test_load_points_on_a_lattice_are_translates_and_their_mean_is_the_static_result():
    """``load.points = 3`` on the triangular lattice, which is invariant under a translation by a
    column: each point's profile, binned about its own loaded grain, is point 0's. Oracles: the
    translation symmetry (each layer's transmitted force within the relaxations' bound of point
    0's; every bin within the same relative bound of the largest, with the two end bins merged:
    x = -L/2 and x = +L/2 are one place of the periodic layer, and a grain exactly there falls in
    either by round-off); the static result is the mean of the points' profiles (numpy, exactly
    as documented) with their standard error; the loads sit where the protocol puts them."""
    comm = Communicator()
    res, layer, h = response_run.run(comm, points=3)
    pts = res["static_points"]
    g = layer.geometry
    Lx, d = g["length"][0], g["mean_diameter"]
    st = res["static"]
    assert len(pts) == 3 and st["points"] == 3 and st["converged"]
    assert len({q["loaded_gid"] for q in pts}) == 3
    for p, q in enumerate(pts):
        target = g["lo"][0] + Lx * (0.5 + p / 3.0)
        assert abs(rsp.relative_x(q["loaded_position"][0], target, Lx)) < d
        assert q["loaded_position"][1] == pytest.approx(pts[0]["loaded_position"][1], abs=1e-9 * h)  # the top row
        assert q["reference"]["converged"] and q["static"]["converged"]
    meta = [{"n": g["n_grains"], "u_ref": q["reference"]["unbalanced"], "u_static": q["static"]["unbalanced"],
             "force": res["force"], "mean_contact_force": q["reference"]["mean_contact_force"]} for q in pts]

    def merged(q):
        s = np.array(q["dsigma_yy"])
        s[:, 0] += s[:, -1]
        return s[:, :-1]

    s0 = merged(pts[0])
    for q, m in zip(pts[1:], meta[1:]):
        # each layer's sum is the transmitted force within N (u_ref + u_static) <f_c> / F of the
        # exact one (``_residual_bound``), for both points
        tol = _residual_bound(m) + _residual_bound(meta[0])
        assert np.all(np.abs(np.array(q["transmitted_over_F"]) - pts[0]["transmitted_over_F"]) <= tol)
        # a bin: the residual forces act as extra point loads of at most that fraction of F,
        # whose largest bin response is at most that of F under the load (the largest bin)
        assert np.max(np.abs(merged(q) - s0)) <= tol * np.max(np.abs(s0)), (np.max(np.abs(merged(q) - s0)), tol)
        assert abs(q["bottom_share"] - pts[0]["bottom_share"]) <= tol
    stack = np.array([q["dsigma_yy"] for q in pts])
    assert np.allclose(st["dsigma_yy"], stack.mean(axis=0), rtol=0, atol=1e-15 * np.abs(stack).max())
    assert np.allclose(st["dsigma_yy_sem"], stack.std(axis=0, ddof=1) / math.sqrt(3), rtol=1e-12, atol=0)
    assert res["reactions"]["bottom_share"] == pytest.approx(np.mean([q["bottom_share"] for q in pts]), rel=1e-15)
    assert res["dynamic"] == []


def test_tolerance_note_is_the_residual_bound():
    """The start-of-run note: the bound 2 N tol / fraction (``_residual_bound`` with both
    relaxations at the tolerance), silent below 1 % of F, and the tolerance it suggests meets it."""
    assert response.residual_share(90000, 1e-9, 0.01) == pytest.approx(0.018, rel=1e-12)
    assert response.residual_share(144, 1e-9, 0.01) == pytest.approx(
        _residual_bound({"n": 144, "u_ref": 1e-9, "u_static": 1e-9, "mean_contact_force": 1.0, "force": 0.01}) - 1e-9)
    assert response.tolerance_note(10000, 1e-8, 0.01) is not None and "0.02 F" in response.tolerance_note(10000, 1e-8, 0.01)
    assert response.tolerance_note(144, 1e-9, 0.01) is None
    suggested = float(response.tolerance_note(90000, 1e-9, 0.01).split("at most ")[1].split(" ")[0])
    assert response.residual_share(90000, suggested, 0.01) <= 0.01 * 1.01      # (2 significant digits)
    # "auto" is the tolerance whose bound is 1 % of F, silent; a number is taken as given
    deck = {"relax": {"force_tolerance": "auto"}, "load": {"fraction": 0.02}}
    auto = response.relax_tolerance(deck, 90000)
    assert response.residual_share(90000, auto, 0.02) == pytest.approx(0.01, rel=1e-12)
    assert response.tolerance_note(90000, auto, 0.02) is None
    deck["relax"]["force_tolerance"] = 1e-7
    assert response.relax_tolerance(deck, 90000) == 1e-7


def test_lattice_response_with_a_fixed_top_splits_the_load():
    comm = Communicator()
    res, layer, h = response_run.run(comm, top="fixed")
    sh = res["reactions"]
    bound = _residual_bound({"n": layer.geometry["n_grains"], "u_ref": res["reference"]["unbalanced"],
                             "u_static": res["static"]["unbalanced"], "force": res["force"],
                             "mean_contact_force": res["reference"]["mean_contact_force"]})
    # global balance: the two rows take the whole load; the load, under the fixed row, goes mostly
    # into it (a bar fixed at both ends loaded at a from the top sends (H - a) / H up)
    assert sh["top_share"] + sh["bottom_share"] == pytest.approx(1.0, abs=bound)
    assert sh["top_share"] > 0.5
    pg = res["_per_grain"]
    sums, _ = _row_sums(pg["dM_yy"], layer.geometry["y"], h)
    below = -sums[:-1] / h / res["force"]     # the bands below the loaded grain (row 10)
    assert np.all(np.abs(below - sh["bottom_share"]) <= bound)


def test_lattice_response_under_a_rigid_top_goes_down():
    comm = Communicator()
    res, layer, h = response_run.run(comm, top="rigid")
    meta = {"n": layer.geometry["n_grains"], "u_ref": res["reference"]["unbalanced"],
            "u_static": res["static"]["unbalanced"], "force": res["force"],
            "mean_contact_force": res["reference"]["mean_contact_force"]}
    bound = _residual_bound(meta)
    # the rigid row is held at its reference force: at equilibrium it takes none of the load. The
    # balance includes the row's own residual M (a + C v), which the free grains' bound does not
    # cover; each state's relaxation criterion (mean |R| < 1e-9 <f_c> over the 144 grains, the row's
    # included) bounds all residuals by 144e-9 <f_c> = 1.4e-5 F per state: 1e-4 (measured 6.6e-6)
    sh = res["reactions"]
    assert sh["top_share"] + sh["bottom_share"] == pytest.approx(1.0, abs=1e-4)
    assert abs(sh["top_share"]) < 1e-4
    sums, _ = _row_sums(res["_per_grain"]["dM_yy"], layer.geometry["y"], h)
    # the load is on row 10 (under the rigid row 11): the bands of rows 1 .. 9 carry F; row 10's
    # band holds the loaded grain at its middle height, whose load enters its sum at y_load:
    # Y2 S_top + Y1 S_bot + y_load (-F) with S_top = 0 and S_bot = F gives -h F / 2
    assert np.all(np.abs(-sums[:9] / h / res["force"] - sh["bottom_share"]) <= bound)
    assert -sums[9] / h / res["force"] == pytest.approx(0.5, abs=10 * bound)


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_lattice_response_same_on_one_and_two_ranks(tmp_path, lattice_runs):
    out = tmp_path / "r2.npz"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.join(ROOT, "tests", "mpi", "response_run.py"),
                        str(out)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    d = np.load(out)
    one = lattice_runs[0.01]
    assert np.array_equal(d["dM_yy"], one["dM"])      # the engine's sums are exact: same bits
    assert np.array_equal(d["dsigma"], np.asarray(one["res"]["static"]["dsigma_yy"]))


# -- replication -----------------------------------------------------------------------------------

def _frictional_packing(comm, m=8, seed=5):
    """A jittered, compressed triangular lattice of m x m polydisperse spheres in a 2D periodic
    cell, run 300 steps with friction and spin so that the contacts carry tangential history."""
    R = 0.1e-3
    rng = np.random.default_rng(seed)
    a = 2.0 * R * 0.997
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    x = (i + 0.5 * (j % 2) + 0.25) * a
    y = (j + 0.5) * a * math.sqrt(3) / 2
    pos = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    pos[:, :2] += rng.uniform(-0.01 * R, 0.01 * R, (m * m, 2))
    radii = R * rng.uniform(0.99, 1.01, m * m)
    vel = np.zeros((m * m, 3))
    vel[:, :2] = rng.normal(0.0, 0.05, (m * m, 2))
    spin = np.zeros((m * m, 3))
    spin[:, 2] = rng.normal(0.0, 500.0, m * m)
    params = {"young": 72e9, "poisson": 0.2, "friction": 0.5, "restitution": 0.9}
    L = np.array([m * a, m * a * math.sqrt(3) / 2, 0.0])
    case = granular_case(comm, pos, radii, 2500.0, "hertz_mindlin", params, np.zeros(3), L, 1e-8, 0.1 * R,
                          velocities=vel, angular_velocities=spin, dimension=2, viscous_damping=2e4)
    case.sim.run(300)
    return case


def _by_gid(sim, name):
    e = sim.elements
    o = np.argsort(e.gid[:e.n_owned])
    return getattr(e, name)[:e.n_owned][o]


def test_replicated_packing_has_the_original_contact_forces():
    comm = Communicator()
    case = _frictional_packing(comm)
    sim = case.sim
    assert np.max(np.abs(sim.contacts.history)) > 0.0   # tangential history to copy
    big = replicate(comm, case, (2, 3))
    n = case.n_elements
    assert big.n_elements == 6 * n
    assert np.allclose(big.sim.cell.length[:2], sim.cell.length[:2] * [2, 3], rtol=1e-15)
    a, b = response.contact_table(sim), response.contact_table(big.sim)
    assert len(b["gid_i"]) == 6 * len(a["gid_i"])
    # each pair of the copy, mapped to the original's gids (ordered), has the original's force
    # on its lower-gid grain (a pair whose order the renumbering reversed has the opposite force)
    oi, oj = b["gid_i"] % n, b["gid_j"] % n
    swap = oi > oj
    key_b = np.where(swap, oj, oi) * (1 << 31) + np.where(swap, oi, oj)
    key_a = a["gid_i"] * (1 << 31) + a["gid_j"]
    pos = np.searchsorted(key_a, key_b)
    assert np.array_equal(key_a[pos], key_b)
    fb = np.where(swap[:, None], -b["force"], b["force"])
    scale = np.max(np.abs(a["force"]))
    assert np.max(np.abs(fb - a["force"][pos])) < 1e-12 * scale      # geometry shifted by k L: round-off
    # and the copies follow the original's dynamics: forces and velocities after 20 more steps
    # from rest (a new case computes the forces of its initial state, which with moving grains
    # adds one tangential increment v_rel dt to the history; at rest the increment is zero, so
    # the original at rest with its forces recomputed is the same state)
    for c in (sim, big.sim):
        c.elements.v[:] = 0.0
        c.elements.w[:] = 0.0
    sim.elements.f[:] = 0.0      # compute_forces adds to zeroed forces
    sim.elements.t[:] = 0.0
    sim.compute_forces()
    sim.run(20)
    big.sim.run(20)
    for name in ("f", "v", "w"):
        orig = _by_gid(sim, name)
        rep = _by_gid(big.sim, name).reshape(6, n, 3)
        ref = np.max(np.abs(orig)) + 1e-300
        assert np.max(np.abs(rep - orig[None])) < 1e-10 * ref, name   # measured 5e-12: round-off of x + k L


def test_replicate_refuses_bad_copies():
    comm = Communicator()
    case, _ = response_run.lattice_case(comm, nx=6, ny=6)
    with pytest.raises(ValueError, match="copies"):
        replicate(comm, case, (0, 2))
    with pytest.raises(ValueError, match="not periodic"):
        replicate(comm, case, (1, 1, 2))


# -- the driver --------------------------------------------------------------------------------------

@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_driver_short_deck_on_two_ranks(tmp_path):
    out = tmp_path / "resp"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.response", "--config", SHORT,
                        "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=1800, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    for f in ("response.json", "response.csv", "response.h5", "response.png", "response_vtk/response.pvd"):
        assert (out / f).exists(), f
    s = json.loads((out / "response.json").read_text())
    r = s["result"]
    assert s["n_ranks"] == 2 and s["finished"]
    st = r["static"]
    assert st["converged"] and r["reference"]["converged"]
    n = r["geometry"]["n_grains"]
    bound = n * (r["reference"]["unbalanced"] + st["unbalanced"]) * r["reference"]["mean_contact_force"] / r["force"]
    # all of the load reaches the base (dead-load top), up to the unbalanced forces
    assert r["reactions"]["bottom_share"] == pytest.approx(1.0, abs=bound + 1e-9)
    # a disordered packing: each layer's sum is the transmitted force within the scatter of the
    # contact points about its faces (layers of 2 d; measured within 8 %)
    tr = np.asarray(st["transmitted_over_F"])
    assert np.all(np.abs(tr - 1.0) < 0.25) and abs(tr.mean() - 1.0) < 0.1
    assert len(r["dynamic"]) == 3 and len(st["dsigma_yy"]) == len(st["depth"])
    # bad input: one line, exit 2, before any work
    q = subprocess.run([sys.executable, "-m", "pardem.drivers.response", "--config", SHORT, "--set",
                        "replicate.copies=[0, 1]", "--out", str(tmp_path / "bad")], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert q.returncode == 2 and "replicate.copies" in q.stderr and not (tmp_path / "bad").exists()


# -- restart ---------------------------------------------------------------------------------------

def _result_without_timings(summary):
    r = dict(summary["result"])
    r.pop("seconds")
    return r


def _tiny_deck(every):
    """Driver arguments of a tiny deck with capped relaxations (not converged: restarts are tested,
    not physics) and a checkpoint every ``every`` steps, all kept."""
    return ["--config", SHORT, "--set", "sample.n=128", "--set", "preparation.max_rate=2e5",
            "--set", "preparation.servo_rate=2e5", "--set", "preparation.max_steps=1200",
            "--set", "relax.max_steps=300", "--set", "relax.check_every=100", "--set", "dynamic.times=[0.5]",
            "--set", "output.plot=false", "--set", f"checkpoint.every_steps={every}",
            "--set", "checkpoint.keep=100000", "--set", "checkpoint.every_seconds=0"]


def _run_response(args, out):
    """The response driver on 2 ranks; returns its summary."""
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.response", "--quiet"] + args
                       + ["--out", str(out)], capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads((out / "response.json").read_text())


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_driver_restart_in_every_stage_is_bit_for_bit(tmp_path):
    """A run killed in any stage resumes from its last checkpoint and ends with the uninterrupted
    run's response, bit for bit (same 2 ranks): the uninterrupted run A writes a checkpoint every
    130 steps (not a multiple of the checks: inside a check interval, where a kill leaves them);
    B restarts from A's checkpoint inside the preparation and is stopped by --steps inside the
    reference relaxation, restarted and stopped inside the dynamic stage, then inside the static
    relaxation, then restarted to the end. Oracle: A's outputs (an independent, uninterrupted
    computation); every float is compared exactly (the JSON keeps 17 digits). The deck is tiny
    and its relaxations capped (not converged: the restart, not the physics, is tested)."""
    import csv
    every = 130
    tiny = _tiny_deck(every)
    go = _run_response

    a = go(tiny, tmp_path / "a")
    assert a["finished"] and a["stage"] == "done" and a["result"]["force"] > 0.0
    steps = a["stage_steps"]
    # the stages' steps from the run's start: prepare, replicate_open (no step), reference, dynamic, static
    assert steps["replicate_open"] == 0 and sum(steps.values()) == a["steps"]
    assert min(steps["prepare"], steps["reference"], steps["dynamic"], steps["static"]) >= 3
    p_end = steps["prepare"]
    r_end = p_end + steps["reference"]
    d_end = r_end + steps["dynamic"]
    # a periodic checkpoint of A inside the preparation, off its checks (every 200 steps)
    k = (p_end // 2) // every * every
    assert k > 0 and k % 200 != 0
    ck = tmp_path / "a" / "checkpoints" / f"checkpoint-{k:010d}.h5"
    assert ck.exists()
    previous, out = ck, None
    for i, stop in enumerate([(p_end + r_end) // 2, (r_end + d_end) // 2, d_end + steps["static"] // 2, None]):
        out = tmp_path / f"b{i}"
        s = go(["--restart", str(previous)] + (["--steps", str(stop)] if stop else []), out)
        assert s["restarted_from"] == str(previous)
        if stop is not None:
            assert not s["finished"] and s["respond_stage"] == ("reference", "dynamic", "static")[i], s["stopped"]
            previous = s["checkpoints"][-1]
    assert s["finished"] and s["steps"] == a["steps"]
    assert _result_without_timings(s) == _result_without_timings(a)
    with open(tmp_path / "a" / "response.csv", newline="") as fh:
        full = list(csv.DictReader(fh))
    with open(out / "response.csv", newline="") as fh:
        again = list(csv.DictReader(fh))
    assert again == full
    # the perturbation snapshots (the dynamic one, written by b2, and the static one) in one collection
    pvd = (out / "response_vtk" / "response.pvd").read_text()
    assert pvd.count("<DataSet") == 2 and "b2/response_vtk/response-000.vtu" in pvd
    assert s["stage_steps"] == steps        # the stage clock is carried across the restarts


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_driver_restart_between_load_points_is_bit_for_bit(tmp_path):
    """``load.points = 2``: a run restarted from its checkpoint inside the second point's
    reference relaxation (the first point's load taken off, its static response kept only in the
    checkpoint) ends with the uninterrupted run's result, bit for bit (same 2 ranks). Oracle: the
    uninterrupted run."""
    every = 130
    args = _tiny_deck(every) + ["--set", "load.points=2"]
    a = _run_response(args, tmp_path / "a")
    r = a["result"]
    assert a["finished"] and len(r["static_points"]) == 2 and r["static"]["points"] == 2
    p0, p1 = r["static_points"]
    assert p0["loaded_gid"] != p1["loaded_gid"]
    start = a["stage_steps"]["prepare"] + p0["reference"]["steps"] + a["stage_steps"]["dynamic"] + p0["static"]["steps"]
    k = (start // every + 1) * every
    assert start < k < start + p1["reference"]["steps"]
    ck = tmp_path / "a" / "checkpoints" / f"checkpoint-{k:010d}.h5"
    b = _run_response(["--restart", str(ck)], tmp_path / "b")
    assert b["finished"] and b["steps"] == a["steps"]
    assert _result_without_timings(b) == _result_without_timings(a)
