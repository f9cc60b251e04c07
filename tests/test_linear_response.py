"""Static linear response of a contact network and effective medium theory
(pardem.physics.linear_response, pardem.physics.effective_medium, pardem.protocols.moduli_check).

Checks: a two-grain contact against the Hertz and Mindlin laws written out (normal and
tangential stiffness, a rigid rotation turns the force, spin and rolling are free); on a prepared
packing the stiffness matrix is the engine kernel's own linearisation (central differences of
``hertz_mindlin.compute`` under a random displacement, rotation and affine strain: forces, torques
and the Love-Weber stress); the solver's answer does not depend on the pinned grain or the
regularisation and solves the unregularised system; the affine tensor's invariants equal the sums
over the contacts, and Walton's closed form equals those sums on an ideal network and bounds them
on the packing through the force heterogeneity; the entry point gives the same moduli from a
checkpoint on 1 and 2 ranks; the isotropic protocol's relaxed moduli (its ramped increments)
equal the static ones within the Hertz nonlinearity at the strain, the relaxation residual and the
sliding of the weakest contacts, in 3D and 2D, where one-step increments fall far outside.
"""
import os

import numpy as np

from pardem import restart
import pytest

from pardem.io.deck_file import load_deck
from pardem.engine.state import Elements
from pardem.parallel.communicator import Communicator
from pardem.physics import effective_medium as emt
from pardem.physics import hertz_mindlin
from pardem.physics import linear_response as lr
from pardem.physics.hertz_mindlin import effective_moduli
from pardem.protocols import isotropic as iso
from pardem.engine.packing import network
from pardem.protocols import stages
from pardem.protocols import moduli_check

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SMALL = os.path.join(ROOT, "drivers", "isotropic_small.toml")
P0 = 1e6
N = 200
G, NU = 30e9, 0.2
E_STAR, G_STAR = effective_moduli(2.0 * G * (1.0 + NU), NU)


@pytest.fixture(scope="module")
def packing():
    """A frictionless FIRE packing of 200 glass spheres at 1 MPa (the isotropic protocol's
    preparation), its gathered network and its Hertz-Mindlin ``Network``."""
    deck = load_deck(iso.SCHEMA, SMALL, [f"sample.n={N}", f"preparation.pressures=[{P0}]",
                                         'preparation.relaxation="fire"'])
    case, info = stages.prepare(Communicator(), deck, P0)
    assert info["converged"]
    sim = case.sim
    g = moduli_check.gather_network(sim)
    net = lr.hertz_mindlin_branches(g["n"], g["i"], g["j"], g["d"], g["radius"], g["volume"], E_STAR, G_STAR)
    return {"deck": deck, "case": case, "sim": sim, "g": g, "net": net,
            "strain": 0.01 * network(sim)["mean_overlap_ratio"]}


# ---------------------------------------------------------------------------------------------
# two grains

def two_grains(delta=1e-7, R=1e-4):
    x = np.array([[0.0, 0.0, 0.0], [2.0 * R - delta, 0.0, 0.0]])
    return lr.hertz_mindlin_network(x, np.array([R, R]), np.full(3, 1.0), [0], [1], np.zeros((1, 3)),
                                    E_STAR, G_STAR), R, delta


def test_two_grains_against_hertz_and_mindlin():
    net, R, delta = two_grains()
    rs = R / 2.0
    hertz = lambda dl: 4.0 / 3.0 * E_STAR * np.sqrt(rs) * dl**1.5          # noqa: E731
    kn = (hertz(delta * (1 + 1e-6)) - hertz(delta * (1 - 1e-6))) / (2e-6 * delta)
    kt = 4.0 * G / (2.0 - NU) * np.sqrt(rs * delta)                         # docs/physics.md section 8
    fn = hertz(delta)
    r = 2.0 * R - delta
    H = lr.stiffness_matrix(net, scale=R).toarray()
    np.testing.assert_allclose(H, H.T, rtol=0, atol=1e-12 * np.abs(H).max())

    def load(u, th):
        return lr.load_increments(net, u=np.asarray(u, float), theta=np.asarray(th, float))

    h = 1e-3 * delta
    # grain 1 pushed towards 0: 0 is pushed away by kn h (central difference of Hertz: rtol 1e-9)
    F, T = load([[0, 0, 0], [-h, 0, 0]], np.zeros((2, 3)))
    np.testing.assert_allclose(F[0], [-kn * h, 0, 0], rtol=1e-9)
    np.testing.assert_allclose(F[1], -F[0], rtol=1e-15)
    # grain 1 moved sideways: Mindlin spring drags 0 along (kt h), the normal force turns (-fn/r h);
    # the torques are l n x (kt h y) on both, l = R - delta/2
    F, T = load([[0, 0, 0], [0, h, 0]], np.zeros((2, 3)))
    np.testing.assert_allclose(F[0], [0, (kt - fn / r) * h, 0], rtol=1e-12)
    np.testing.assert_allclose(T[0], [0, 0, (R - delta / 2) * kt * h], rtol=1e-12)
    np.testing.assert_allclose(T[1], T[0], rtol=1e-12)
    # a rigid rotation phi about z of the pair: no spring works, the force rotates: dF_0 = -fn phi e_y
    phi = 1e-6
    F, T = load([[0, 0, 0], [0, phi * r, 0]], [[0, 0, phi], [0, 0, phi]])
    np.testing.assert_allclose(F[0], [0, -fn * phi, 0], rtol=1e-9, atol=1e-12 * fn * phi)
    np.testing.assert_allclose(T, 0.0, atol=1e-12 * fn * phi * R)
    # spin about the normal, and rolling of 1 on 0 without slip, are free
    for u, th in (([[0, 0, 0], [0, 0, 0]], [[phi, 0, 0], [phi, 0, 0]]),
                  ([[0, 0, 0], [0, 0, 0]], [[0, 0, phi], [0, 0, -phi]])):
        F, T = load(u, th)
        np.testing.assert_allclose(F, 0.0, atol=1e-12 * fn)
        np.testing.assert_allclose(T, 0.0, atol=1e-12 * fn * R)


# ---------------------------------------------------------------------------------------------
# the engine's kernel, linearised

def engine_loads(net, g, radius, u, theta, eps, h, dt=1e-8):
    """Forces, torques [n, 3] and Love-Weber stress [3, 3] of ``hertz_mindlin.compute`` after the
    displacement ``h (eps x + u)`` and rotation ``h theta`` (as velocities over one step dt, the
    history starting at zero, the cell deforming at ``h eps / dt``)."""
    n = g["n"]
    # centres reconstructed from the branch vectors: grain rows with x_j = x_i + d - shift; any
    # positions with the right branch vectors do: put grain i at the origin of each pair
    i, j = net.i.astype(np.int32), net.j.astype(np.int32)
    m = len(i)
    # one element per contact end: 2 m rows, so that every pair is independent of the others
    x = np.zeros((2 * m, 3))
    x[m:] = net.d
    ii, jj = np.arange(m, dtype=np.int32), np.arange(m, 2 * m, dtype=np.int32)
    rad = np.concatenate([radius[i], radius[j]])
    U = np.concatenate([u[i], u[j]])
    TH = np.concatenate([theta[i], theta[j]])
    el = Elements.from_spheres(x + h * (x @ eps.T + U), rad, 2500.0)
    el.v[:] = h * U / dt
    el.w[:] = h * TH / dt
    prm = hertz_mindlin.Params(young=2.0 * G * (1.0 + NU), poisson=NU, friction=1e3)
    acc = np.zeros(10)
    hertz_mindlin.compute(prm, el, ii, jj, np.zeros((m, 3)), dt, np.zeros((m, 3)), np.diag(eps) * h / dt, acc)
    F = np.zeros((n, 3))
    T = np.zeros((n, 3))
    np.add.at(F, i, el.f[:m])
    np.add.at(F, j, el.f[m:])
    np.add.at(T, i, el.t[:m])
    np.add.at(T, j, el.t[m:])
    V = net.volume * np.prod(1.0 + h * np.diag(eps))
    return F, T, acc[:9].reshape(3, 3) / V


def test_stiffness_matrix_is_the_engine_kernel_linearised(packing):
    """``-H z + f_aff`` and the first-order stress equal central differences of the engine's
    Hertz-Mindlin kernel. Tolerance 1e-5 of the largest entry: the difference step is 1e-4 of the
    mean overlap, so the O(h^2) error is (h / delta)^2 <= 1e-5 even for the weakest contacts
    (delta > 3e-2 of the mean here); round-off is 1e-16 delta / h = 1e-12 (measured 2e-7)."""
    net, g = packing["net"], packing["g"]
    rng = np.random.default_rng(7)
    n = net.n
    u = rng.normal(size=(n, 3))
    theta = rng.normal(size=(n, 3)) / float(np.mean(g["radius"]))
    eps = np.array([[0.3, 0.0, 0.0], [0.0, -0.7, 0.0], [0.0, 0.0, 0.2]])   # the kernel's cell: diagonal rates
    mean_delta = float(np.mean(g["radius"][net.i] + g["radius"][net.j] - net.r))
    h = 1e-4 * mean_delta
    Fp, Tp, Sp = engine_loads(net, g, g["radius"], u, theta, eps, h)
    Fm, Tm, Sm = engine_loads(net, g, g["radius"], u, theta, eps, -h)
    dF, dT, dS = (Fp - Fm) / (2 * h), (Tp - Tm) / (2 * h), (Sp - Sm) / (2 * h)
    scale = lr.default_scale(net)
    z = np.concatenate([u, theta * scale], axis=1).ravel()
    gen = (-(lr.stiffness_matrix(net, scale) @ z) + lr.affine_forces(net, eps, scale)).reshape(n, 6)
    np.testing.assert_allclose(gen[:, :3], dF, rtol=0, atol=1e-5 * np.abs(dF).max())
    np.testing.assert_allclose(gen[:, 3:] * scale, dT, rtol=0, atol=1e-5 * np.abs(dT).max())
    dsig = lr.stress_increment(net, eps, u, theta, stress=packing["g"]["stress"])
    np.testing.assert_allclose(dsig, dS, rtol=0, atol=1e-5 * np.abs(dS).max())
    # the stress of the network is the engine's (same forces, same sums: round-off)
    np.testing.assert_allclose(net.stress(), g["stress"], rtol=0, atol=1e-12 * P0)


# ---------------------------------------------------------------------------------------------
# the solver

def test_solution_independent_of_pin_and_regularisation(packing):
    """Rattlers removed, one grain pinned, Tikhonov shift plus refinement: the moduli do not depend
    on which grain is pinned or on the shift (1e-9: the refinement's residual, 1e-13, times the
    condition number of the pinned backbone matrix, 1.4e3 here, all eigenvalues positive; measured
    2e-15), the unregularised system is solved, and the relaxed moduli lie below the affine ones
    (the relaxation lowers the elastic energy)."""
    net, g = packing["net"], packing["g"]
    a = lr.moduli(net, stress=g["stress"], full=False)
    rel = lr.Relaxation(net)
    other = int(np.nonzero(rel.kept)[0][-1])
    b = lr.moduli(net, stress=g["stress"], full=False, pin=other, reg=1e-6)
    for k in ("K_relaxed", "mu_relaxed"):
        assert b[k] == pytest.approx(a[k], rel=1e-9), k
    assert a["residual"] < 1e-12 and b["residual"] < 1e-12
    assert 0.0 < a["K_relaxed"] < a["K_affine"] and 0.0 < a["mu_relaxed"] < a["mu_affine"]
    # the backbone: every kept grain has at least 2 kept contacts, and is one cluster
    deg = np.bincount(rel.sub.i, minlength=net.n) + np.bincount(rel.sub.j, minlength=net.n)
    assert np.all(deg[rel.kept] >= 2) and np.all(deg[~rel.kept] == 0)
    assert a["backbone_grains"] == int(rel.kept.sum()) > 0.9 * net.n


# ---------------------------------------------------------------------------------------------
# affine moduli and effective medium theory

def test_affine_invariants_are_the_contact_sums(packing):
    """The isotropic invariants of the affine 6 x 6 stiffness, and the affine K of the bulk mode,
    equal ``effective_medium.affine_sums`` (an identity: round-off, 1e-10)."""
    net, g = packing["net"], packing["g"]
    m = lr.moduli(net, stress=g["stress"])
    s = emt.affine_sums(net.r, net.fn, net.kn, net.kt, net.volume)
    assert s["pressure"] == pytest.approx(P0, rel=1e-3)         # the preparation's pressure tolerance
    assert m["K_iso_affine"] == pytest.approx(s["K"], rel=1e-10)
    assert m["mu_iso_affine"] == pytest.approx(s["mu"], rel=1e-10)
    assert m["K_affine"] == pytest.approx(s["K"], rel=1e-10)    # the bulk mode needs no fabric average


def test_walton_closed_form_on_an_ideal_network():
    """Equal spheres, equal forces, branch vectors along the 6 axes of an icosahedron (a spherical
    5-design: the fourth moment is isotropic): Walton's closed form equals the central sums and the
    affine tensor is isotropic (round-off, 1e-12)."""
    t = (1.0 + np.sqrt(5.0)) / 2.0
    axes = np.array([[0, 1, t], [0, -1, t], [1, t, 0], [-1, t, 0], [t, 0, 1], [-t, 0, 1]], float)
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    R, delta, n_grains, reps = 1e-4, 2e-7, 12, 6
    nc = len(axes) * reps                                       # Z = 2 * 36 / 12 = 6
    a = np.sqrt(R / 2.0 * delta)
    fn = np.full(nc, 4.0 / 3.0 * E_STAR * a * delta)
    phi = 0.64
    V = n_grains * 4.0 / 3.0 * np.pi * R**3 / phi
    d = np.tile(axes, (reps, 1)) * 2.0 * R                      # r = 2 R: the closed form's geometry
    idx = np.arange(nc) % n_grains
    net = lr.Network(n_grains, idx, (idx + 1) % n_grains, d, fn, np.full(nc, 2.0 * E_STAR * a),
                     np.full(nc, 8.0 * G_STAR * a), np.full(nc, R), np.full(nc, R), V)
    s = emt.affine_sums(net.r, net.fn, net.kn, net.kt, V)
    Z, phi2 = emt.packing_Z_phi(n_grains, nc, np.full(n_grains, 4.0 / 3.0 * np.pi * R**3), V)
    assert Z == 6.0 and phi2 == pytest.approx(phi, rel=1e-15)
    w = emt.hertz_mindlin_emt(Z, phi2, s["pressure"], G, NU)
    assert s["K_central"] == pytest.approx(w["K"], rel=1e-12)
    assert s["mu_central"] == pytest.approx(w["mu"], rel=1e-12)
    C = np.zeros((6, 6))
    for k in range(6):
        C[:, k] = lr.voigt_stress(lr.stress_increment(net, lr.voigt_strain(k)))
    np.testing.assert_allclose(C[0, 0] - C[0, 1], 2.0 * C[5, 5], rtol=1e-12)       # isotropic
    np.testing.assert_allclose(np.diag(C)[:3], C[0, 0], rtol=1e-12)
    np.testing.assert_allclose(np.diag(C)[3:], C[5, 5], rtol=1e-12)
    K, mu = lr.isotropic_averages(C)
    assert K == pytest.approx(s["K"], rel=1e-12) and mu == pytest.approx(s["mu"], rel=1e-12)
    assert emt.heterogeneity(fn) == pytest.approx(1.0, rel=1e-14)


def test_emt_against_the_packing(packing):
    """Walton's closed form with the packing's own Z, phi and p against the central affine sums of
    its contacts: their ratio is ``<s_c (fn r)^(1/3)> / <fn r>^(1/3)`` exactly, with s_c =
    R*^(1/3) r^(5/3) / ((R/2)^(1/3) (2R)^(5/3)) the size factor of a contact (R the volume-mean
    radius), so it lies between min s_c and max s_c times J = <(fn r)^(1/3)> / <fn r>^(1/3) <= 1
    (Jensen). Measured: ratio 0.9275, J 0.9278, s_c in [0.894, 1.097] (radii +-5 %: (R_min / R_v)^2
    and (R_max / R_v)^2), Z = 6.29, phi = 0.629: Walton overestimates K and mu by 7.8 %."""
    net, g = packing["net"], packing["g"]
    radius = g["radius"]
    Z, phi = emt.packing_Z_phi(net.n, net.n_contacts, 4.0 / 3.0 * np.pi * radius**3, net.volume)
    s = emt.affine_sums(net.r, net.fn, net.kn, net.kt, net.volume)
    w = emt.hertz_mindlin_emt(Z, phi, s["pressure"], G, NU)
    ratio_K, ratio_mu = s["K_central"] / w["K"], s["mu_central"] / w["mu"]
    assert ratio_mu == pytest.approx(ratio_K, rel=1e-12)       # kt / kn is the same for every contact
    Rv = float(np.cbrt(np.mean(radius**3)))
    ri, rj = radius[net.i], radius[net.j]
    sc = np.cbrt(ri * rj / (ri + rj)) * net.r ** (5.0 / 3.0) / (np.cbrt(Rv / 2.0) * (2.0 * Rv) ** (5.0 / 3.0))
    fr = net.fn * net.r
    J = float(np.mean(np.cbrt(fr)) / np.cbrt(np.mean(fr)))
    assert J < 1.0
    assert sc.min() * J <= ratio_K <= sc.max() * J
    # the exact form of the ratio (an identity of the Hertz law: round-off)
    assert ratio_K == pytest.approx(float(np.mean(sc * np.cbrt(fr)) / np.cbrt(np.mean(fr))), rel=1e-12)
    # heterogeneity(fn) differs from J by the spread of r (+-5 %) entering as r^(1/3) inside and
    # outside the mean: at most (1.05 / 0.95)^(1/3) - 1 = 3.4 % (measured 4e-4)
    assert emt.heterogeneity(net.fn) == pytest.approx(J, rel=0.034)


# ---------------------------------------------------------------------------------------------
# the entry point on a checkpoint, on 1 and 2 ranks

CHECK_SCRIPT = """
import json, sys
from pardem.parallel.communicator import Communicator
from pardem.protocols import moduli_check
comm = Communicator()
out = moduli_check.from_checkpoint(comm, sys.argv[1], {"shear_modulus": 30e9, "poisson": 0.2, "friction": 0.3},
                                   float(sys.argv[2]))
if comm.is_root:
    print(json.dumps(out))
"""


@pytest.mark.mpi
def test_moduli_check_on_a_checkpoint_on_two_ranks(packing, tmp_path):
    """``moduli_check.from_checkpoint`` of the prepared packing's checkpoint on 2 ranks equals the
    1-rank evaluation of the same file (the network is gathered in gid order: the same matrix;
    the branch vectors of pairs across a slab boundary may differ in the last bit, which the
    solve amplifies by its condition number, 1.4e3: 1e-9), and the live packing's."""
    import json
    import shutil
    import subprocess
    import sys
    path = tmp_path / "prepared.h5"
    restart.save(packing["case"].sim, extras=packing["case"].extras, path=str(path))
    e = packing["strain"]
    mat = {"shear_modulus": G, "poisson": NU, "friction": 0.3}
    one = moduli_check.from_checkpoint(Communicator(), str(path), mat, e)
    live = moduli_check.static_moduli(packing["sim"], mat, e)
    mpiexec = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
    p = subprocess.run([mpiexec, "-n", "2", sys.executable, "-c", CHECK_SCRIPT, str(path), repr(e)],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    two = json.loads(p.stdout.strip().splitlines()[-1])
    for k in ("K_affine", "K_relaxed", "mu_affine", "mu_relaxed", "K_iso_relaxed", "mu_iso_relaxed"):
        assert two["tangent"][k] == pytest.approx(one["tangent"][k], rel=1e-9), k
        assert live["tangent"][k] == pytest.approx(one["tangent"][k], rel=1e-9), k
    for k in ("K_relaxed", "mu_relaxed"):
        assert two["protocol"][k] == pytest.approx(one["protocol"][k], rel=1e-9), k
    assert two["emt"]["K_EMT"] == pytest.approx(one["emt"]["K_EMT"], rel=1e-12)
    assert one["max_ft_over_fn"] == 0.0          # the prepared state: frictionless, no history


# ---------------------------------------------------------------------------------------------
# static against dynamic: the protocol's relaxed moduli against the linear response

@pytest.fixture(scope="module")
def prepared_files(packing, tmp_path_factory):
    """Checkpoints of the prepared packings (restored fresh for every measurement): the 3D
    fixture's, and a 2D one (100 spheres in the plane z = 0, FIRE, 1 MPa)."""
    d = tmp_path_factory.mktemp("prepared")
    restart.save(packing["case"].sim, extras=packing["case"].extras, path=str(d / "p3.h5"))
    deck2 = load_deck(iso.SCHEMA, SMALL, ["sample.n=100", f"preparation.pressures=[{P0}]", "domain.dimension=2",
                                          'preparation.relaxation="fire"'])
    case2, info2 = stages.prepare(Communicator(), deck2, P0)
    assert info2["converged"]
    restart.save(case2.sim, extras=case2.extras, path=str(d / "p2.h5"))
    return {3: (str(d / "p3.h5"), packing["deck"]), 2: (str(d / "p2.h5"), deck2)}


def residual_loads(sim):
    """Unbalanced forces and torques [n, 3] of the owned grains in gid order (one rank), the
    viscous drag of the step removed (as ``engine.packing.balance``); 2D: in-plane components only."""
    el = sim.elements
    n = el.n_owned
    vh = el.v[:n] - 0.5 * sim.dt * el.f[:n] * el.inv_mass[:n, None]
    wh = el.w[:n] - 0.5 * sim.dt * el.t[:n] * el.inv_inertia[:n, None]
    order = np.argsort(el.gid[:n])
    force = (el.f[:n] + sim.viscous_damping * el.mass[:n, None] * vh)[order]
    torque = (el.t[:n] + sim.viscous_damping * el.inertia[:n, None] * wh)[order]
    if sim.cell.dimension == 2:
        force[:, 2] = 0.0
        torque[:, :2] = 0.0
    return force, torque


def residual_error(sim, loads, eps, fn, e, modulus):
    """The relaxation's residual error relative to ``e * modulus``: the stress change that removing
    the unbalanced ``loads`` of the state of ``sim`` would make (``Relaxation.equilibrium_correction``,
    linear), as the modulus function ``fn`` of the strain mode ``eps`` reads it."""
    h = moduli_check.gather_network(sim)
    net = lr.hertz_mindlin_branches(h["n"], h["i"], h["j"], h["d"], h["radius"], h["volume"], E_STAR, G_STAR)
    ds, _ = lr.Relaxation(net).equilibrium_correction(*loads, h["stress"])
    return abs(fn(ds, eps)) / (e * abs(modulus))


def mode_measures(net, stress, e, modes, friction):
    """Per strain mode of ``modes`` (``moduli_check.MODES``), from the static relaxed response:
    ``chi = sum_c (E_c / E) (e s_n,c / delta_c)^2``, the energy-weighted square of each contact's
    relative overlap change over the increment (Hertz: ``delta = 3 fn / (2 kn)``), and ``S`` the
    share of the mode's energy ``eps : C : eps V`` held by the tangential springs of the contacts
    whose linear tangential force ``kt |w| e`` exceeds the Coulomb cap ``friction * fn``."""
    rel = lr.Relaxation(net)
    sub = rel.sub
    delta = 1.5 * sub.fn / sub.kn
    out = {}
    for name, eps, _ in modes:
        r = rel.response(eps, stress)
        s_n, w, _, _ = lr.contact_measures(sub, eps, r["u"], r["theta"])
        w2 = np.einsum("ij,ij->i", w, w)
        E = sub.kn * s_n**2 + sub.kt * w2
        chi = float(np.sum(E * (e * s_n / delta) ** 2) / np.sum(E))
        slide = sub.kt * np.sqrt(w2) * e > friction * sub.fn
        energy = abs(float(np.einsum("ab,ab->", eps, r["relaxed"]))) * sub.volume
        out[name] = {"chi": chi, "S": float(np.sum(sub.kt[slide] * w2[slide]) / energy)}
    return out


def measure(path, deck, dim, friction, ramp):
    """The protocol's moduli (``isotropic.moduli``, the deck's tolerances and strain rule) of the
    packing of checkpoint ``path`` with ``friction`` and ``ramp`` steps per increment, the static
    ones of the same state (``moduli_check.static_moduli``, as the sweep computes them), the
    residual errors of every relaxed state and the mode measures."""
    case = restart.load_case(Communicator(), path)
    sim = case.sim
    sim.compute_forces()
    sim.viscous_damping = deck["preparation"]["damping"]
    sim.elements.v[:] = 0.0
    sim.elements.w[:] = 0.0
    d = dict(deck, material=dict(deck["material"], friction=friction), moduli=dict(deck["moduli"], ramp_steps=ramp))
    e = 0.01 * network(sim)["mean_overlap_ratio"]
    static = moduli_check.compact(moduli_check.static_moduli(sim, d["material"], e))
    g = moduli_check.gather_network(sim)
    net = lr.hertz_mindlin_branches(g["n"], g["i"], g["j"], g["d"], g["radius"], g["volume"], E_STAR, G_STAR)
    modes = moduli_check.MODES[dim]
    # the prepared state's own residual error (the K increment starts from it)
    c_start = residual_error(sim, residual_loads(sim), modes[0][1], modes[0][2], e, static["K_static"])
    measures = mode_measures(net, g["stress"], e, modes, friction)
    # at every equilibrium check of a relaxation, its residual error; the last is the end state's
    c_end = {}
    run = stages.SweepRun()
    mode = {name: (eps, fn) for name, eps, fn in modes}

    def on_check(sim_, b):
        name = run.state["stage"]
        eps, fn = mode[name]
        c_end[name] = residual_error(sim_, residual_loads(sim_), eps, fn, e, static[f"{name}_static"])
    run.on_check = on_check
    mod = iso.moduli(sim, d, e, run=run)
    return {"static": static, "moduli": mod, "compare": moduli_check.compare(static, mod), "c_end": c_end,
            "measures": measures, "strain": e, "c_start": c_start}


@pytest.mark.parametrize("dim, friction", [(3, 0.3), (3, 1e3), (2, 0.3)])
def test_relaxed_moduli_equal_the_static_ones(prepared_files, dim, friction):
    """The protocol's relaxed K and mu (``isotropic.moduli``: each increment ramped over
    ``moduli.ramp_steps`` steps, relaxed to the deck's criteria) against the static secants of
    the same packing (``moduli_check.static_moduli``, the summary's ``moduli.static``), in 3D
    with the deck's friction 0.3 and without sliding (friction 1e3), and in 2D.

    Relative window, from the physics of the two measurements:

    * nonlinearity, ``3 chi``: the static secant is the trapezoid of the tangents at both ends of
      the increment, exact to first order in each contact's overlap change x = e s_n / delta
      (for Hertz k ~ delta^(1/2) the mean of k over the increment is 1 + x/4 - x^2/24, the
      trapezoid 1 + x/4 - x^2/16; the incremental Mindlin spring and the non-affine path add
      terms of the same order), so the two differ by O(x^2) weighted by the contacts' share of the
      energy: chi = <x^2>_E (3e-4 here; e * dlnK/de itself, x/4 ~ 4e-3, cancels); factor 3 for
      the O(1) coefficients;
    * relaxation, ``3 (c_start + c_end)``: the dynamic stresses are measured at a force residual of
      ``equilibrium.force_tolerance`` (1e-4), the static ones at exact equilibrium; c is the stress
      change that removing the measured unbalanced loads would make (linear solve), over e times
      the modulus, at the start and at the end of the increment;
    * sliding, ``S`` (lower side only): the static response assumes no sliding; a contact that
      slides loses at most its whole tangential spring, which lowers the relaxed modulus by at most
      the share of the mode's energy held by that spring (the relaxed state minimises the energy:
      removing springs cannot lower it by more than their energy in the old minimiser); S sums it
      over the contacts whose linear tangential force at strain e exceeds the Coulomb cap.

    The affine K of the first ramp step equals the static tangent at zero strain to
    ``sqrt(chi) / ramp``: its strain is e / ramp, and the secant over a step differs from the tangent
    by x / 4 per contact, whose energy-weighted mean is at most sqrt(chi) / 4 (Cauchy-Schwarz).
    Measured (3D, 0.3): K 2.2e-5, mu -2.5e-3 (S = 3.3e-3: one contact in 630 slides); (3D, 1e3): K
    2.2e-5, mu -3.8e-4; 2D: K -4e-5, mu -2.0e-3. In ONE step (``ramp_steps = 1``) mu comes out
    3.7 % low at friction 1e3, far outside the window: checked too.
    """
    path, deck = prepared_files[dim]
    ramp = deck["moduli"]["ramp_steps"]
    assert ramp == iso.DEFAULT_RAMP_STEPS
    m = measure(path, deck, dim, friction, ramp)
    c_start, cmp = m["c_start"], m["compare"]
    for name in ("K", "mu"):
        chi, S = m["measures"][name]["chi"], m["measures"][name]["S"]
        # the mu increment starts where the K increment's relaxation ended
        c = (c_start if name == "K" else m["c_end"]["K"]) + m["c_end"][name]
        tol = 3.0 * (chi + c)
        diff = cmp[f"{name}_difference"]
        assert -tol - S <= diff <= tol, (name, diff, chi, c, S)
        if friction > 1.0:
            assert S == 0.0
    assert abs(cmp["K_affine_difference"]) < np.sqrt(m["measures"]["K"]["chi"]) / ramp, cmp
    assert m["moduli"]["K_relax_converged"] and m["moduli"]["mu_relax_converged"]
    if friction > 1.0:
        one = measure(path, deck, dim, friction, 1)
        chi = m["measures"]["mu"]["chi"]
        assert one["compare"]["mu_difference"] < -10.0 * 3.0 * (chi + m["c_end"]["mu"]), one["compare"]
