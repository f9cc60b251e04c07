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
(``pardem.engine.granular.restore``): meaningful for a checkpoint written at the end of a
preparation (the protocol's ``stage = "K"`` with no increment applied yet), approximate
otherwise (the tangential forces of a strained state are ignored).

Measured (200 glass spheres, 1 MPa, no-slip contacts, relaxation to a force residual of 1e-6):
with the protocol's strain e = 0.01 <delta / d> applied quasi-statically (a cell rate over 4000
steps) the dynamic relaxation gives the static secant's K to 2e-5 and mu to 5e-4
(tests/test_linear_response.py). Applied in ONE step, as ``isotropic.increment`` does, the relaxed
moduli come out low, in proportion to e: mu by 3.9 %, 1.0 %, 0.27 % and K by 6e-4, 2e-4, 6e-5 at
e, e / 4, e / 16. The ringing after the jump loads and unloads every contact, and the Mindlin
spring's unloading rescale (``hertz_mindlin.unload_rescale``) shrinks the tangential forces on
each unloading half-cycle without giving them back on loading.
"""
import numpy as np

from pardem.engine import granular
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
    part = {"gid": e.gid[:n_own].copy(), "radius": e.radius[:n_own].copy(),
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
    gi = np.concatenate([p["gi"] for p in parts]).astype(np.int64)
    gj = np.concatenate([p["gj"] for p in parts]).astype(np.int64)
    dd = np.concatenate([p["d"] for p in parts])
    o = np.lexsort((gj, gi))          # a fixed order: the result does not depend on the ranks
    delta = np.concatenate([p["delta"] for p in parts])[o]
    ht = np.concatenate([p["ht"] for p in parts])[o]
    return {"n": len(gid), "i": np.searchsorted(gid, gi[o]), "j": np.searchsorted(gid, gj[o]), "d": dd[o],
            "radius": radius, "volume": sim.cell.volume, "stress": stress, "delta": delta, "ht": ht}


def static_moduli(sim, material, strain=None):
    """Static moduli of the packing of ``sim`` (collective; module docstring). ``material``: the
    isotropic deck's ``[material]`` (shear_modulus, poisson, friction); ``strain``: the protocol's
    increment e (None: no secant and no sliding estimate)."""
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
    touch = g["delta"] > 0.0
    fn = net.fn
    tangent = lr.moduli(net, stress=g["stress"], friction=material.get("friction"), strain=strain)
    out = {"tangent": tangent,
           "max_ft_over_fn": float(np.max(g["ht"][touch] / np.where(fn > 0, fn, 1.0))) if len(fn) else 0.0}
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


def from_checkpoint(comm, path, material=None, strain=None):
    """``static_moduli`` of the state stored in checkpoint ``path`` (collective); ``material``
    None: the grains of the checkpoint's contact parameters (young, poisson, friction)."""
    case = granular.restore(comm, path)
    case.sim.compute_forces()
    if material is None:
        prm = case.constants["params"]
        material = {"shear_modulus": prm["young"] / (2.0 * (1.0 + prm["poisson"])), "poisson": prm["poisson"],
                    "friction": prm.get("friction", 0.0)}
    return static_moduli(case.sim, material, strain)
