"""Independent check of the isotropic protocol's moduli: the static linear response of the contact
network (``pardem.physics.linear_response``) and effective medium theory
(``pardem.physics.effective_medium``) evaluated on a simulation's current state.

``static_moduli(sim, material, strain)`` (collective: the network is gathered on rank 0, solved
there, the result broadcast) is meant for the equilibrated packing of ``isotropic.prepare``,
before ``isotropic.moduli`` strains it: tangential forces are assumed zero (the protocol clears
the history), see ``linear_response``. It returns a JSON-friendly dict::

    tangent:   K/mu affine and relaxed at zero strain, the 6 x 6 stiffnesses, their isotropic
               averages, backbone size, solver residual, sliding fractions at ``strain``
    protocol:  the protocol's secant moduli at its strain e to second order (trapezoid of the
               tangents at both ends of each increment; ``linear_response.protocol_moduli``)
    emt:       Walton's closed form with the packing's Z, phi, p; the affine sums over the
               contacts; the heterogeneity factor <fn^1/3> / <fn>^1/3 that relates them

``from_checkpoint(comm, path, material, strain)`` does the same on the state of a checkpoint
(``pardem.restart.load``): meaningful for a checkpoint written at the end of a
preparation (the protocol's ``stage = "K"`` with no increment applied yet), approximate
otherwise (the tangential forces of a strained state are ignored).

``compact(static)`` is the isotropic summary's ``details[k]["static"]`` record (``K_static``,
``mu_static``: the protocol's secants; tangents, sliding fractions, EMT), ``compare(record, moduli)``
its ``details[k]["moduli"]["static"]`` (static beside relaxed, ``relaxed / static - 1``).
The gathered network is the same bits on any number of ranks (branch vectors from the owned
positions plus the kernel's image shift), so the static moduli are too.

2D (``[domain] dimension = 2``): the in-plane modes of the 2D protocol, ``diag(-1, -1, 0)`` with
``K = dp / (-dA / A)``, ``p = -(s_xx + s_yy) / 2``, and the shear (``evaluate_2d``,
``secant_moduli``); the out-of-plane degrees of freedom decouple exactly.

Measured (200 glass spheres, 1 MPa, relaxation to the deck's force residual 1e-4; strain e = 0.01
<delta / d>, tests/test_linear_response.py): with the protocol's ramp (``moduli.ramp_steps`` =
2000) relaxed / static - 1 is 2.2e-5 for K and -3.8e-4 for mu with no-slip contacts (friction
1e3), -2.5e-3 for mu with friction 0.3 (one contact in 630 slides: the static response assumes
none; the tangential energy above the Coulomb cap of the sliding contacts is 2.2e-3 of the
mode's). Applied in ONE step (``ramp_steps = 1``) the relaxed moduli come out low, in proportion to
e: mu by 3.9 %, 1.0 %, 0.27 % and K by 6e-4, 2e-4, 6e-5 at e, e / 4, e / 16: the ringing after the
jump loads and unloads every contact, and the Mindlin spring's unloading rescale
(``hertz_mindlin.unload_rescale``) shrinks the tangential forces on each unloading half-cycle
without giving them back on loading. 100 disks (2D) at 1 MPa: 3e-6 (K), -2.5e-4 (mu) with the
ramp, -4.0 % (mu) in one step.
"""
import numpy as np

from pardem import restart
from pardem.physics import effective_medium as emt
from pardem.physics import linear_response as lr
from pardem.physics.contact_frame import pair_geometry
from pardem.physics.hertz_mindlin import effective_moduli


def gather_network(sim):
    """The global pair list on rank 0 (collective): dict with ``n``, ``i``, ``j`` (rows in gid
    order), ``d`` [m, 3] branch vectors as the kernels see them, ``radius`` [n], ``volume``,
    ``stress`` [3, 3] (the last force evaluation's, tension positive), ``max_ft_over_fn`` (largest
    stored tangential force over the normal force); None on the other ranks."""
    e, c = sim.elements, sim.contacts
    n_own = e.n_owned
    once = c.counted_once(n_own)
    d, _, _, delta = pair_geometry(c.i, c.j, c.shift, e.x, e.radius)
    ht = np.sqrt(np.einsum("ij,ij->i", c.history[:, :3], c.history[:, :3]))
    part = {"gid": e.gid[:n_own].copy(), "radius": e.radius[:n_own].copy(), "x": e.x[:n_own].copy(),
            "gi": e.gid[c.i[once]], "gj": e.gid[c.j[once]], "d": d[once], "delta": delta[once],
            "ht": ht[once]}
    stress = sim.global_stress()
    parts = sim.comm.gather(part)
    if not sim.comm.is_root:
        return None
    gid = np.concatenate([p["gid"] for p in parts]).astype(np.int64)
    radius = np.concatenate([p["radius"] for p in parts])
    order = np.argsort(gid)
    gid, radius = gid[order], radius[order]
    x = np.concatenate([p["x"] for p in parts])[order]
    gi = np.concatenate([p["gi"] for p in parts]).astype(np.int64)
    gj = np.concatenate([p["gj"] for p in parts]).astype(np.int64)
    dd = np.concatenate([p["d"] for p in parts])
    o = np.lexsort((gj, gi))          # a fixed order: the result does not depend on the ranks
    delta = np.concatenate([p["delta"] for p in parts])[o]
    ht = np.concatenate([p["ht"] for p in parts])[o]
    i, j = np.searchsorted(gid, gi[o]), np.searchsorted(gid, gj[o])
    # the branch vectors from the owned positions (the same bits on any number of ranks) plus the
    # image shift of the kernel's: a ghost's stored position is an image, whose difference may
    # round differently (a last-bit change that the solve would amplify by its condition number)
    length = sim.cell.length
    plain = x[j] - x[i]
    dd = plain + np.round((dd[o] - plain) / length) * length
    return {"n": len(gid), "i": i, "j": j, "d": dd, "dim": int(sim.cell.dimension),
            "radius": radius, "volume": sim.cell.volume, "stress": stress, "delta": delta, "ht": ht}


def static_moduli(sim, material, strain=None):
    """Static moduli of the packing of ``sim`` (collective; module docstring). ``material``: the
    isotropic deck's ``[material]`` (shear_modulus, poisson, friction); ``strain``: the protocol's
    increment e (None: no secant and no sliding estimate). None, on every rank, for a packing
    without a backbone (no grain has two contacts: a gas, e.g. a preparation capped by
    ``preparation.max_steps`` before it jammed)."""
    g = gather_network(sim)
    out = None
    if g is not None:
        out = evaluate(g, material, strain)
    return sim.comm.bcast(out)


def evaluate(g, material, strain=None):
    """``static_moduli`` on a gathered network ``g`` (``gather_network``'s dict; pure)."""
    G, nu = float(material["shear_modulus"]), float(material["poisson"])
    e_star, g_star = effective_moduli(2.0 * G * (1.0 + nu), nu)
    net = lr.hertz_mindlin_branches(g["n"], g["i"], g["j"], g["d"], g["radius"], g["volume"], e_star, g_star)
    if not lr.backbone(net)[0].any():
        return None      # nothing rigid to strain (the relaxation would refuse it)
    touch = g["delta"] > 0.0
    fn = net.fn
    max_ft = float(np.max(g["ht"][touch] / np.where(fn > 0, fn, 1.0))) if len(fn) else 0.0
    if int(g.get("dim", 3)) == 2:
        return evaluate_2d(g, net, material, strain, e_star, g_star, max_ft)
    tangent = lr.moduli(net, stress=g["stress"], friction=material.get("friction"), strain=strain)
    out = {"dimension": 3, "tangent": tangent, "max_ft_over_fn": max_ft}
    if strain is not None:
        out["protocol"] = lr.protocol_moduli(g["n"], g["i"], g["j"], g["d"], g["radius"], g["volume"],
                                             g["stress"], e_star, g_star, strain)
        out["strain"] = float(strain)
    Z, phi = emt.packing_Z_phi(g["n"], net.n_contacts, 4.0 / 3.0 * np.pi * g["radius"] ** 3, g["volume"])
    sums = emt.affine_sums(net.r, fn, net.kn, net.kt, net.volume)
    closed = emt.hertz_mindlin_emt(Z, phi, sums["pressure"], G, nu)
    out["emt"] = {"Z": Z, "phi": phi, "pressure": sums["pressure"], "K_EMT": closed["K"], "mu_EMT": closed["mu"],
                  "K_sum": sums["K"], "mu_sum": sums["mu"], "K_sum_central": sums["K_central"],
                  "mu_sum_central": sums["mu_central"], "heterogeneity": emt.heterogeneity(fn),
                  "K_sum_over_EMT": sums["K_central"] / closed["K"],
                  "mu_sum_over_EMT": sums["mu_central"] / closed["mu"]}
    return out


# the 2D protocol's modes (pardem.protocols.isotropic, 2D mode): in-plane bulk compression and shear
BULK_2D = np.diag([-1.0, -1.0, 0.0])


def bulk_2d_from(ds, eps=BULK_2D):
    """The 2D ``K = d p / (-dA / A)`` [Pa], ``p = -(s_xx + s_yy) / 2``, of the stress increment
    ``ds`` [3, 3] of the in-plane strain ``eps`` (per unit strain)."""
    return float((ds[0, 0] + ds[1, 1]) / 2.0 / (eps[0, 0] + eps[1, 1]))


MODES = {3: (("K", lr.BULK, lr.bulk_from), ("mu", lr.SHEAR, lr.shear_from)),
         2: (("K", BULK_2D, bulk_2d_from), ("mu", lr.SHEAR, lr.shear_from))}


def secant_moduli(g, e_star, g_star, strain, modes, **relax_options):
    """``linear_response.protocol_moduli`` for any list of ``modes`` ``(name, eps [3, 3], modulus
    function)``: each increment's secant at strain e as the trapezoid of the tangents at its start
    and at its end (the start moved by e times the linear response), each increment starting where
    the previous ended. Pure; ``g`` a gathered network. Returns ``K_affine, K_relaxed, ...`` and
    the tangents at both ends (``*_tangents``) [Pa].
    """
    return lr.protocol_moduli(g["n"], g["i"], g["j"], g["d"], g["radius"], g["volume"], g["stress"], e_star,
                              g_star, strain, modes=modes, **relax_options)


def evaluate_2d(g, net, material, strain, e_star, g_star, max_ft):
    """``evaluate`` of a 2D network (centres in z = 0, the 2D stress convention: ``g["volume"] =
    L_x L_y t``): the tangent moduli of the 2D modes at zero strain, sliding fractions, and the
    protocol's secants; no 6 x 6 tensor and no EMT (Walton's form is 3D). The out-of-plane
    degrees of freedom (u_z, theta_x, theta_y) decouple from the in-plane ones exactly (every
    branch vector has d_z = 0, so the z -> -z reflection is a symmetry) and no in-plane strain
    loads them."""
    rel = lr.Relaxation(net)
    s0 = np.asarray(g["stress"], dtype=float)
    tangent = {"n_grains": int(net.n), "n_contacts": int(net.n_contacts), "backbone_grains": int(rel.kept.sum()),
               "backbone_contacts": int(rel.contacts.sum()), "pressure": float(-(s0[0, 0] + s0[1, 1]) / 2.0)}
    res = []
    friction = material.get("friction")
    for name, eps, fn in MODES[2]:
        r = rel.response(eps, s0)
        tangent[f"{name}_affine"], tangent[f"{name}_relaxed"] = fn(r["affine"], eps), fn(r["relaxed"], eps)
        res.append(r["residual"])
        if friction is not None and strain is not None:
            _, w, _, _ = lr.contact_measures(rel.sub, eps, r["u"], r["theta"])
            ft = rel.sub.kt * np.sqrt(np.einsum("ij,ij->i", w, w)) * abs(float(strain))
            tangent[f"{name}_sliding_fraction"] = float(np.mean(ft > float(friction) * rel.sub.fn))
    tangent["residual"] = float(max(res))
    out = {"dimension": 2, "tangent": tangent, "max_ft_over_fn": max_ft}
    if strain is not None:
        out["protocol"] = secant_moduli(g, e_star, g_star, strain, MODES[2])
        out["strain"] = float(strain)
    return out


def compact(static):
    """The summary's ``static`` record of a ``static_moduli`` result: ``K_static``, ``mu_static``
    (the protocol's relaxed secants at its strain; the tangents at zero strain without one), the
    affine ones, the tangents at zero strain, sliding fractions, backbone, solver residual and, in
    3D, Walton's EMT [Pa]."""
    t = static["tangent"]
    sec = static.get("protocol")
    out = {"K_static": (sec or t)["K_relaxed"], "mu_static": (sec or t)["mu_relaxed"],
           "K_affine_static": (sec or t)["K_affine"], "mu_affine_static": (sec or t)["mu_affine"],
           "K_tangent": t["K_relaxed"], "mu_tangent": t["mu_relaxed"],
           "K_affine_tangent": t["K_affine"], "mu_affine_tangent": t["mu_affine"],
           "strain": static.get("strain"), "residual": t["residual"], "backbone_grains": t["backbone_grains"],
           "backbone_contacts": t["backbone_contacts"], "max_ft_over_fn": static["max_ft_over_fn"]}
    if sec is not None:
        # the affine tangent at the start of each increment (the shear's starts after the bulk's):
        # what the first step of a ramped increment measures
        out["K_affine_start"] = sec["K_affine_tangents"][0]
        out["mu_affine_start"] = sec["mu_affine_tangents"][0]
    for k in ("K_sliding_fraction", "mu_sliding_fraction"):
        if k in t:
            out[k] = t[k]
    if "emt" in static:
        out["K_EMT"], out["mu_EMT"] = static["emt"]["K_EMT"], static["emt"]["mu_EMT"]
    return out


def compare(static, mod):
    """``moduli.static`` of the summary: the static (``compact``) and the relaxed moduli (``mod``,
    ``isotropic.moduli``'s dict) side by side and ``relaxed / static - 1``; the affine ones against
    the static secant (one-step increment) or the tangent at the start of the increment (ramped:
    the affine moduli come from its first step)."""
    out = {"K_static": static["K_static"], "mu_static": static["mu_static"],
           "K_relaxed": mod["K_relaxed"], "mu_relaxed": mod["mu_relaxed"],
           "K_difference": mod["K_relaxed"] / static["K_static"] - 1.0,
           "mu_difference": mod["mu_relaxed"] / static["mu_static"] - 1.0}
    one_step = int(mod.get("ramp_steps", 1)) == 1
    for m in ("K", "mu"):
        ref = static.get(f"{m}_affine_static" if one_step else f"{m}_affine_start")
        if ref is not None:
            out[f"{m}_affine_static"] = ref
            out[f"{m}_affine_difference"] = mod[f"{m}_affine"] / ref - 1.0
    return out


def from_checkpoint(comm, path, material=None, strain=None):
    """``static_moduli`` of the state stored in checkpoint ``path`` (collective); ``material``
    None: the grains of the checkpoint's contact parameters (young, poisson, friction)."""
    sim = restart.load(comm, path)
    sim.compute_forces()
    if material is None:
        prm = sim.system.contacts.params
        material = {"shear_modulus": prm["young"] / (2.0 * (1.0 + prm["poisson"])), "poisson": prm["poisson"],
                    "friction": prm.get("friction", 0.0)}
    return static_moduli(sim, material, strain)
