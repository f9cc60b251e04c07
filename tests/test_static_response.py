"""Static linear point-load response of a contact network (``linear_response.StaticResponse``,
``pardem.protocols.response.static_linear`` / ``linear_measure`` / ``contact_changes``).

Oracles:
(a) the dynamic relaxation of the protocol at a load small enough that no contact changes state
    (counted: 0 opened, closed, slid) equals the static solve, within the bound of the relaxations'
    residual forces plus the Hertz nonlinearity and the neglected reference tangential forces
    (each computed from the run);
(b) superposition: the static responses add exactly (round-off), and the relaxed response to two
    loads equals the sum of the static ones within (a)'s bound;
(c) force balance: through every horizontal cut below the load the contacts carry exactly the load
    (equilibrium of the grains above), the supports take it all, for each kind of top row;
(d) reciprocity (Betti), force-force and force-torque;
(e) a brute-force twin: the stiffness matrix, reduced to the supports' free DOFs, equals the
    central-difference Jacobian of the engine's own Hertz-Mindlin kernel on a few grains.
"""
import os

import numpy as np
import pytest

from pardem.engine import fixes as fx
from pardem.engine.state import Elements
from pardem.io.deck_file import load_deck
from pardem.parallel.communicator import Communicator
from pardem.physics import hertz_mindlin
from pardem.physics import linear_response as lr
from pardem.protocols import response

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHORT = os.path.join(ROOT, "drivers", "response_short.toml")
FRACTION = 1e-4          # load / mean contact force: far below any contact's state change


def deck_for(top="free", tol=1e-11):
    return load_deck(response.SCHEMA, SHORT, [
        "sample.n=120", f"load.fraction={FRACTION}", "dynamic.times=[]", f'boundary.top="{top}"',
        f"relax.force_tolerance={tol}", "relax.kinetic_tolerance=1e-24", "relax.check_every=100",
        "output.perturbation_vtk=false", "output.plot=false"])


@pytest.fixture(scope="module")
def relaxed():
    """The protocol's run on a 120-grain disordered layer (free top, friction 0.3): the result,
    the layer, the reference and loaded states."""
    comm = Communicator()
    deck = deck_for()
    case, _ = response.prepared(comm, deck)
    layer = response.make_layer(comm, case, deck)
    res = response.respond(layer, deck)
    return {"res": res, "layer": layer, "deck": deck, "ref": layer.ref, "cur": response.gather_state(layer.sim)}


@pytest.fixture(scope="module")
def layers():
    """Opened (not relaxed) layers of one packing for each kind of top row, with their gathered
    states: the static solve needs a network, not an equilibrium."""
    comm = Communicator()
    out = {}
    for top in ("free", "rigid", "fixed"):
        deck = deck_for(top)
        case, _ = response.prepared(comm, deck)
        layer = response.make_layer(comm, case, deck)
        response.apply_load(layer, 1.0)
        out[top] = (layer, response.gather_state(layer.sim), deck)
    return out


def bound(res, layer, ref, linear):
    """Relative bound of |relaxed - static| over the largest static value (bins or contacts):
    share: each relaxation leaves residual forces of mean |R| = unbalanced x <f_c> on N grains,
    extra loads of at most N (u_ref + u_static) <f_c> / F of F, whose response is at most that
    share of F's (the lattice tests' argument, tests/test_response.py); Hertz: f ~ delta^(3/2)
    makes the second-order part of a contact's change (1/6) df / f of its linear part; tangential:
    the reference tangential forces, left out of H, add ft d(delta) / (2 delta) = |ft| / (3 fn) of
    the normal change while a contact opens (``unload_rescale``); 1e-9: the solve's residual and
    round-off."""
    st = res["static"]
    n = layer.geometry["n_grains"]
    share = n * (st["unbalanced"] + res["reference"]["unbalanced"]) * res["reference"]["mean_contact_force"] / res["force"]
    c = ref["contacts"]
    fn = -np.einsum("ij,ij->i", c["force"], c["normal"])
    ft = np.linalg.norm(c["force"] + fn[:, None] * c["normal"], axis=1)
    df = np.linalg.norm(linear["force"], axis=1)
    return share + np.max(df / fn) / 6.0 + np.max(ft / fn) / 3.0 + 1e-9


def test_static_and_relaxed_responses_agree_where_no_contact_changes_state(relaxed):
    res, layer, ref, cur, deck = relaxed["res"], relaxed["layer"], relaxed["ref"], relaxed["cur"], relaxed["deck"]
    st = res["static"]
    assert st["converged"] and res["reference"]["converged"]
    ch = st["contact_changes"]
    assert (ch["opened"], ch["closed"], ch["slid"]) == (0, 0, 0), ch
    lin = response.static_linear(layer, ref, deck)
    tol = bound(res, layer, ref, lin)
    assert tol < 1e-3            # the comparison means something (measured: 4e-4)
    # contact by contact (the same pairs: none opened or closed)
    assert np.array_equal(cur["contacts"]["gid_i"], ref["contacts"]["gid_i"])
    assert np.array_equal(cur["contacts"]["gid_j"], ref["contacts"]["gid_j"])
    d_rel = cur["contacts"]["force"] - ref["contacts"]["force"]
    scale = np.abs(lin["force"]).max()
    assert np.abs(d_rel - lin["force"]).max() <= tol * scale
    # the profiles, measured by the same code (the summary's and a direct one)
    a, b = np.asarray(st["dsigma_yy"]), np.asarray(st["linear"]["dsigma_yy"])
    assert np.abs(a - b).max() <= tol * np.abs(a).max()
    direct = response.linear_measure(layer, ref, deck, lin)
    assert np.array_equal(np.asarray(direct["dsigma_yy"]), b)
    assert np.allclose(st["transmitted_over_F"], st["linear"]["transmitted_over_F"], rtol=0, atol=tol)
    assert st["linear"]["residual"] < 1e-10


def test_superposition(relaxed):
    """Static: the solve is linear to round-off (1e-9 of the largest change; the solves' residual
    is 1e-12). Relaxed: a second load B added to the loaded state, relaxed again: the change from
    the reference equals static(A) + static(B) within (a)'s bound with both residuals."""
    res, layer, ref, deck = relaxed["res"], relaxed["layer"], relaxed["ref"], relaxed["deck"]
    n = layer.geometry["n_grains"]
    F = res["force"]
    A = np.zeros((n, 3))
    A[layer.loaded_gid, 1] = -F
    # B: a free grain (not a piston: its x load must act) a quarter period away, at mid height
    g = layer.geometry
    target = np.array([g["lo"][0] + 0.75 * g["length"][0], g["lo"][1] + 0.5 * g["length"][1]])
    free = np.asarray(layer.free)
    gap = np.abs(ref["x"][free, :2] - target)
    gb = int(free[np.argmin(np.hypot(np.minimum(gap[:, 0], g["length"][0] - gap[:, 0]), gap[:, 1]))])
    B = np.zeros((n, 3))
    B[gb] = (0.5 * F, -0.8 * F, 0.0)
    sa = response.static_linear(layer, ref, deck, A)
    sb = response.static_linear(layer, ref, deck, B, solver=sa["solver"])
    sab = response.static_linear(layer, ref, deck, A + B, solver=sa["solver"])
    for k in ("u", "theta", "force", "reaction_force"):
        assert np.abs(sab[k] - sa[k] - sb[k]).max() <= 1e-9 * np.abs(sab[k]).max(), k
    # the relaxed response to A + B
    load = fx.ExternalForce([gb], tuple(B[gb]))
    fx.add(layer.sim, load)
    b2, ok, _ = response.relax_layer(layer, deck, "A + B")
    cur = response.gather_state(layer.sim)
    layer.sim.fixes.remove(load)
    assert ok
    assert np.array_equal(cur["contacts"]["gid_i"], ref["contacts"]["gid_i"])
    d_rel = cur["contacts"]["force"] - ref["contacts"]["force"]
    r2 = dict(res, static=dict(res["static"], unbalanced=res["static"]["unbalanced"] + b2["unbalanced"]))
    tol = bound(r2, layer, ref, sab) * 2.0     # loads of F and about F: the share counts both
    assert np.abs(d_rel - sab["force"]).max() <= tol * np.abs(sab["force"]).max()
    assert np.abs(d_rel - sa["force"]).max() > 10 * tol * np.abs(sab["force"]).max()   # B matters


def crossing_sums(layer, ref, lin, y_cut):
    """Vertical force change [N] the contacts crossing ``y = y_cut`` exert on their upper grain."""
    c = ref["contacts"]
    y = ref["x"][:, 1]
    gi = c["gid_i"]
    # the branch vector (periodic along x only) gives the partner's height
    yj = y[gi] + c["normal"][:, 1] * (c["arm_i"] + c["arm_j"])
    up_i = (y[gi] > y_cut) & (yj < y_cut)
    up_j = (yj > y_cut) & (y[gi] < y_cut)
    return lin["force"][up_i, 1].sum() - lin["force"][up_j, 1].sum()


@pytest.mark.parametrize("top", ["free", "rigid", "fixed"])
def test_response_carries_the_load_at_every_depth(layers, top):
    """Each grain above a cut is in equilibrium under its contacts and the load (dead loads and the
    rigid row's force are constant, the pistons hold x only): the contacts crossing any cut below
    the loaded grain carry F upwards on the grains above; the supports take F. Tolerance 1e-9 of
    F: the solve's residual (1e-12) times the network's conditioning."""
    layer, ref, deck = layers[top]
    lin = response.static_linear(layer, ref, deck)
    F = layer.force
    y = ref["x"][:, 1]
    y_load = y[layer.loaded_gid]
    bottom_top, top_low = y[layer.bottom].max(), y[layer.top].min()
    hs = np.sort(np.unique(y[(y > bottom_top) & (y < min(y_load, top_low))]))
    cuts = 0.5 * (hs[1:] + hs[:-1])
    assert len(cuts) > 20
    top_reaction = lin["reaction_force"][layer.top, 1].sum()
    bottom_reaction = lin["reaction_force"][layer.bottom, 1].sum()
    assert top_reaction + bottom_reaction == pytest.approx(F, rel=1e-9)
    if top == "fixed":
        assert top_reaction > 0.1 * F          # the load sits under the clamped row: it takes some
        expect = F - top_reaction
    else:
        assert abs(top_reaction) <= 1e-9 * F   # dead loads and the rigid row take none
        expect = F
    for yc in cuts:
        assert crossing_sums(layer, ref, lin, yc) == pytest.approx(expect, rel=1e-9, abs=1e-9 * F)
    # the top row's motion: none (fixed), one vertical translation (rigid: a tie, exact), grain by
    # grain (free); x and the rotations held in every case
    uy = lin["u"][layer.top, 1]
    assert np.all(lin["u"][layer.top, 0] == 0.0) and np.all(lin["theta"][layer.top] == 0.0)
    if top == "fixed":
        assert np.all(uy == 0.0)
    elif top == "rigid":
        assert np.ptp(uy) == 0.0 and uy[0] != 0.0
    else:
        assert np.ptp(uy) > 0.1 * np.abs(uy).max()


def test_reciprocity(layers):
    """Betti: (displacement at B along b from a unit load at A along a) = (at A along a from B along
    b), for a force-force pair (one a top piston grain, y only) and a force-torque pair (rotation
    against displacement). Tolerance 1e-9: the solves' residual (1e-12) times conditioning."""
    layer, ref, deck = layers["free"]
    n = layer.geometry["n_grains"]
    s0 = response.static_linear(layer, ref, deck)
    free = np.setdiff1d(layer.binned, layer.top)
    free = free[s0["solver"].kept[free]]
    top = layer.top[s0["solver"].kept[layer.top]]
    A, B, C = int(free[3]), int(top[2]), int(free[len(free) // 2])
    a, b = np.array([0.6, -0.8, 0.0]), np.array([0.0, 1.0, 0.0])
    fa = np.zeros((n, 3))
    fa[A] = a
    fb = np.zeros((n, 3))
    fb[B] = b
    tc = np.zeros((n, 3))
    tc[C, 2] = 1.0
    s = response.static_linear(layer, ref, deck, fa, solver=s0["solver"])
    solver = s["solver"]
    sb = solver.solve(fb)
    sc = solver.solve(np.zeros((n, 3)), tc)
    uba, uab = s["u"][B] @ b, sb["u"][A] @ a
    assert abs(uba) > 0.0
    assert uba == pytest.approx(uab, rel=1e-9)
    # unit torque at C: displacement at A along a; unit force at A: rotation of C about z
    uac, thca = sc["u"][A] @ a, s["theta"][C, 2]
    assert abs(thca) > 0.0
    assert uac == pytest.approx(thca, rel=1e-9)


def test_stiffness_is_the_engine_kernels_jacobian():
    """Five disks (2D: the plane's DOFs) touching in a cluster, one of them clamped (the anchor),
    one a piston (x and rotation held): the reduced stiffness ``T^T H T`` equals minus the
    central-difference Jacobian of the generalised forces (forces, torques over the rotation
    scale) of ``hertz_mindlin.compute_all_pairs`` (history zero, the displacement as a velocity
    over one step). Overlaps 1e-2 R, so the pre-stress term (fn / r, 1e-2 of kn) is seen; step
    h = 1e-4 delta: O(h^2) error (h / delta)^2 = 1e-8, round-off 1e-16 delta / h = 1e-12; tolerance
    1e-6 of the largest entry."""
    R = 1e-4
    G, NU = 30e9, 0.2
    E = 2.0 * G * (1.0 + NU)
    delta = 1e-2 * R
    a = 2.0 * R - delta
    x = np.array([[0.0, 0.0, 0.0], [a, 0.0, 0.0], [0.5 * a, a * np.sqrt(0.75), 0.0],
                  [1.5 * a, a * np.sqrt(0.75) * 0.999, 0.0], [-0.5 * a * 1.001, a * np.sqrt(0.75), 0.0]])
    radius = R * np.array([1.0, 1.002, 0.998, 1.001, 1.003])      # every touching pair overlaps by >= 0.008 R
    n = len(x)
    ii, jj = np.triu_indices(n, 1)
    e_star, g_star = hertz_mindlin.effective_moduli(E, NU)
    net = lr.hertz_mindlin_network(x, radius, np.ones(3), ii, jj, np.zeros((len(ii), 3)), e_star, g_star)
    assert net.n_contacts == 7 and (lr.hertz_mindlin_branches(n, net.i, net.j, net.d, radius, 1.0, 1.0, 1.0).n_contacts == 7)
    held = np.zeros((n, 6), bool)
    held[:, list(lr.PLANE_HELD)] = True
    held[0] = True
    held[4, [0, 3, 4, 5]] = True
    sr = lr.StaticResponse(net, held)
    assert sr.kept.all()
    prm = hertz_mindlin.Params(young=E, poisson=NU, friction=1e3)
    dt = 1e-8
    h = 1e-4 * delta

    def loads(z):
        zz = z.reshape(n, 6)
        el = Elements.from_spheres(x + zz[:, :3], radius, 2500.0)
        el.v[:] = zz[:, :3] / dt
        el.w[:] = zz[:, 3:] / sr.scale / dt
        hertz_mindlin.compute_all_pairs(prm, el, np.zeros((n, n, 3)), dt)
        return np.concatenate([el.f, el.t / sr.scale], axis=1).ravel()

    m = sr.T.shape[1]
    J = np.zeros((6 * n, m))
    for k in range(m):
        dz = h * sr.T[:, k].toarray().ravel()
        J[:, k] = (loads(dz) - loads(-dz)) / (2.0 * h)
    K_fd = -(sr.T.T @ J)
    K = sr.K.toarray()
    np.testing.assert_allclose(K, K_fd, rtol=0, atol=1e-6 * np.abs(K).max())
    # the pre-stress and tangential parts are above the tolerance: the test sees them
    fn_over_r = net.fn / net.r
    assert fn_over_r.min() > 100 * 1e-6 * np.abs(K).max() and net.kt.min() > 0.1 * net.kn.max()


def test_bad_inputs():
    net = lr.hertz_mindlin_network(np.array([[0.0, 0, 0], [1.9e-4, 0, 0]]), np.full(2, 1e-4), np.ones(3),
                                   [0], [1], np.zeros((1, 3)), 1e10, 1e10)
    with pytest.raises(ValueError, match="held must be"):
        lr.StaticResponse(net, np.zeros((2, 3), bool))
    with pytest.raises(ValueError, match="no anchor"):
        lr.StaticResponse(net, np.zeros((2, 6), bool))
    held = np.zeros((2, 6), bool)
    held[0] = True
    with pytest.raises(ValueError, match="tie"):
        lr.StaticResponse(net, held, ties=[([0, 1], 0)])
    sr = lr.StaticResponse(net, held)
    assert not sr.kept[1]          # one contact: it rolls about it (a rattler)
    with pytest.raises(ValueError, match="grain 1 is loaded"):
        sr.solve(np.array([[0.0, 0, 0], [1.0, 0, 0]]))


def test_contact_changes_count_sliding_and_opening():
    """A load of 90 % of the mean contact force with friction 1e-3: contacts near the load slide and
    one opens (measured).
    The summary's counts against a brute-force recount from the gathered states (sets of gid
    pairs; the Coulomb limit |ft| >= (1 - 1e-9) mu fn written out): opened and closed equal it,
    ``slid`` (sampled during the load step) is at least the contacts newly at the limit at the end,
    and positive."""
    comm = Communicator()
    deck = load_deck(response.SCHEMA, SHORT, [
        "sample.n=120", "load.fraction=0.9", "load.friction=1e-3", "dynamic.times=[0.5]",
        "relax.force_tolerance=1e-8", "output.perturbation_vtk=false", "output.plot=false"])
    case, _ = response.prepared(comm, deck)
    layer = response.make_layer(comm, case, deck)
    res = response.respond(layer, deck)
    ref, cur = layer.ref, response.gather_state(layer.sim)

    def pairs(c):
        return {(int(a), int(b)) for a, b in zip(c["gid_i"], c["gid_j"])}

    def limit(c):
        out = set()
        for a, b, n, f in zip(c["gid_i"], c["gid_j"], c["normal"], c["force"]):
            fn = -float(n @ f)
            ft = f + fn * n
            if fn > 0 and np.sqrt(ft @ ft) >= (1 - 1e-9) * 1e-3 * fn:
                out.add((int(a), int(b)))
        return out

    ch = res["static"]["contact_changes"]
    p0, p1 = pairs(ref["contacts"]), pairs(cur["contacts"])
    assert ch["opened"] == len(p0 - p1) and ch["closed"] == len(p1 - p0)
    assert ch["opened"] != ch["closed"]       # the count tells them apart (measured: 1 and 0)
    l0, l1 = limit(ref["contacts"]), limit(cur["contacts"])
    assert ch["at_coulomb_limit_reference"] == len(l0) and ch["at_coulomb_limit_loaded"] == len(l1)
    assert ch["slid"] >= len(l1 - l0) and ch["slid"] > 0
