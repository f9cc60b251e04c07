"""Measures of a granular packing from its contacts (collective where they say so).

``contact_forces``: this rank's touching contacts counted once with their elastic forces (the
kernels' geometry; cemented pairs with their cement force); ``balance``: the equilibrium measures
a relaxation checks (pressure, kinetic energy, unbalanced forces; exact sums, the same bits on any
number of ranks); ``network``: the state of a packing (coordination with and without rattlers,
solid fraction, normal force distribution), gathered on rank 0 and broadcast. docs/physics.md
sections 11, 12.
"""
import numpy as np

from pardem.engine.reducer import granular_measures
from pardem.parallel.exact_sum import exact_sum
from pardem.physics import hertz_mindlin, structure
from pardem.physics.contact_frame import pair_geometry


def contact_forces(sim, cement=False):
    """This rank's contacts counted once (lower-gid end owned) and touching: dict of ``gid_i``,
    ``gid_j`` [n_c], ``fn`` [n_c] elastic Hertz normal force [N], ``force`` [n_c, 3] force on i [N],
    ``branch`` [n_c, 3] [m], ``delta`` [n_c] overlap [m], ``dist`` [n_c] centre distance [m].

    ``cement``: with a cemented law, also the pairs apart that hold a cement, and ``force`` the
    whole elastic force of the last evaluation, contact plus cement (``hertz_mindlin``'s cemented
    kernel: ``scale (Sn (delta - delta0) n-part, carried tangential force)``, ``scale`` 1 for an
    intact cement, the fading factor ``-state`` for a broken one); then also ``touching``
    [n_c] (delta > 0), ``intact`` [n_c] (an intact cement) and ``tangential`` [n_c, 3] (the
    Mindlin force alone, for the Coulomb criterion). ``fn`` stays the Hertz part."""
    e, c = sim.elements, sim.contacts
    d, n, dist, delta = pair_geometry(c.i, c.j, c.shift, e.x, e.radius)   # the kernels' geometry
    h = c.history
    cemented = cement and h.shape[1] == hertz_mindlin.WIDTH_CEMENTED
    state = h[:, hertz_mindlin.CEMENT_STATE] if cemented else None
    keep = ((delta > 0.0) | (state != 0.0) if cemented else (delta > 0.0)) & c.counted_once(e.n_owned)
    d, n, dist, delta, h = d[keep], n[keep], dist[keep], delta[keep], h[keep]
    touching = delta > 0.0
    fn = np.zeros(len(delta))
    fn[touching] = c.law.elastic_normal_force(c.params, e.radius[c.i[keep]][touching],
                                              e.radius[c.j[keep]][touching], delta[touching])
    force = h[:, :3] - fn[:, None] * n        # F_i = ft - fn n (contact_frame)
    out = {"gid_i": e.gid[c.i[keep]], "gid_j": e.gid[c.j[keep]], "fn": fn, "force": force,
           "branch": d, "delta": delta, "dist": dist}
    if cement:
        out.update(touching=touching, tangential=h[:, :3].copy(), intact=np.zeros(len(delta), bool))
    if cemented:
        hm, st = hertz_mindlin, state[keep]
        scale = np.where(st > 0.0, 1.0, -st)
        f_cement = scale * float(c.params.cement_normal) * (delta - h[:, hm.CEMENT_DELTA0])
        out["force"] = force + scale[:, None] * h[:, hm.CEMENT_FORCE:hm.CEMENT_FORCE + 3] - f_cement[:, None] * n
        out["intact"] = st > 0.0
    return out


def balance(sim, p0=None):
    """Equilibrium measures (collective): dict with ``pressure`` [Pa], ``kinetic`` = E_k / (N p0
    V_mean) (p0 defaults to p; V_mean the mean sphere volume, also in 2D), ``unbalanced`` = mean
    |F| / mean |f_c| and ``unbalanced_max`` = max |F| / mean |f_c|, ``n_contacts``,
    ``solid_fraction_raw`` (overlaps not removed; 2D: disk areas over the cell area)."""
    e = sim.elements
    n = e.n_owned
    dim = sim.cell.dimension
    vh = e.v[:n] - 0.5 * sim.dt * e.f[:n] * e.inv_mass[:n, None]   # velocity the drag was computed with
    fc = e.f[:n] + sim.viscous_damping * e.mass[:n, None] * vh
    fmag = np.sqrt(np.einsum("ij,ij->i", fc, fc))
    cf = contact_forces(sim)
    fcmag = np.sqrt(np.einsum("ij,ij->i", cf["force"], cf["force"]))
    # exact sums of the per-element and per-contact terms: the same bits on any number of ranks
    # (the equilibrium decisions feed back into the run)
    cols = np.zeros((max(n, len(fcmag)), 4 if dim == 2 else 3))
    cols[:n, 0] = fmag
    cols[:len(fcmag), 1] = fcmag
    cols[:n, 2] = 4.0 / 3.0 * np.pi * e.radius[:n] ** 3
    if dim == 2:
        cols[:n, 3] = np.pi * e.radius[:n] ** 2      # disk areas
    sums = exact_sum(sim.comm, cols)
    counts = sim.comm.sum([n, len(fcmag)])     # integers: exact
    g = [sums[0], counts[0], sums[1], counts[1], sums[2]]
    fmax = sim.comm.max(float(fmag.max()) if n else 0.0)
    stress = sim.global_stress()
    p = sim.cell.pressure(stress)
    # overlaps not removed: sphere volumes over the cell volume (2D: disk areas over its area)
    raw = float(sums[3] / sim.cell.area) if dim == 2 else float(g[4] / sim.cell.volume)
    ref = p if p0 is None else p0
    mean_fc = g[2] / g[3] if g[3] > 0 else 0.0
    ke = sim.kinetic_energy()
    return {"pressure": p, "stress": stress,
            "kinetic": float(ke / (ref * g[4])) if ref > 0 else float("inf"),
            "unbalanced": float(g[0] / g[1] / mean_fc) if mean_fc > 0 else float("inf"),
            "unbalanced_max": float(fmax / mean_fc) if mean_fc > 0 else float("inf"),
            "n_contacts": int(round(g[3])), "mean_contact_force": float(mean_fc),
            "n_elements": int(round(g[1])), "solid_volume": float(g[4]), "solid_fraction_raw": raw}


def remove_rattlers(n, gid_i, gid_j, dim=3):
    """Mask [n] of the non-rattlers and mask [n_c] of the contacts between them: elements with
    fewer than ``dim + 1`` contacts are removed with their contacts, repeatedly
    (``pardem.physics.structure.rattlers``)."""
    return structure.rattlers(n, gid_i, gid_j, dim=dim)


def network(sim, bins=None):
    """State of the packing (collective; the contact network is gathered on rank 0): dict with
    ``p`` [Pa], ``Z``, ``Z_no_rattlers``, ``rattlers`` (count), ``solid_fraction``, ``n_contacts``,
    ``mean_overlap_ratio`` = <delta / d>, and ``force_distribution`` (histogram of f_n / <f_n>:
    ``edges``, ``density``, also ``mean_fn`` [N])."""
    m = granular_measures(sim)
    cf = contact_forces(sim)
    dim = sim.cell.dimension
    e = sim.elements
    parts = sim.comm.gather({"gi": cf["gid_i"], "gj": cf["gid_j"], "fn": cf["fn"],
                             "ratio": cf["delta"] / cf["dist"], "dist": cf["dist"],
                             "gid": e.gid[:e.n_owned], "radius": e.radius[:e.n_owned]})
    n = int(round(float(sim.comm.sum(sim.elements.n_owned))))
    out = None
    if sim.comm.is_root:
        gi = np.concatenate([q["gi"] for q in parts]).astype(np.int64)
        gj = np.concatenate([q["gj"] for q in parts]).astype(np.int64)
        fn = np.concatenate([q["fn"] for q in parts])
        ratio = np.concatenate([q["ratio"] for q in parts])
        dist = np.concatenate([q["dist"] for q in parts])
        o = np.lexsort((gj, gi))        # gid order: the means do not depend on the ranks
        gi, gj, fn, ratio, dist = gi[o], gj[o], fn[o], ratio[o], dist[o]
        alive, live = remove_rattlers(n, gi, gj, dim=dim)
        mean_fn = float(fn.mean()) if len(fn) else 0.0
        edges = np.linspace(0.0, 5.0, 51) if bins is None else bins
        dens, _ = np.histogram(fn / mean_fn if mean_fn > 0 else fn, bins=edges, density=True)
        out = {"Z": 2.0 * len(gi) / n,
               "Z_no_rattlers": 2.0 * int(live.sum()) / max(int(alive.sum()), 1),
               "rattlers": int(n - alive.sum()), "n_contacts": int(len(gi)),
               "mean_overlap_ratio": float(ratio.mean()) if len(ratio) else 0.0,
               "force_distribution": {"edges": edges.tolist(), "density": dens.tolist(),
                                      "mean_fn": mean_fn,
                                      "fraction_above_mean": float(np.mean(fn > mean_fn)) if len(fn) else 0.0}}
        if dim == 2:
            # disk areas (the spheres' sections by z = 0) minus the lens areas, over L_x L_y
            radius = np.zeros(n)
            for q in parts:
                radius[q["gid"]] = q["radius"]
            out["solid_fraction"] = structure.solid_fraction(radius, sim.cell.length[:2], dim=2, i=gi,
                                                             j=gj, dist=dist)[0]
    out = sim.comm.bcast(out)
    if dim == 2:
        out["p"] = sim.cell.pressure(m["stress"])
    else:
        out["p"] = m["pressure"]
        out["solid_fraction"] = m["solid_fraction"]
    return out


__all__ = ["contact_forces", "balance", "remove_rattlers", "network"]
