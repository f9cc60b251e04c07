"""Mixture study: packings of two grain sizes against the size ratio and the
concentration of small grains, prepared frictionless under the pressure servo at one pressure.

A case is one (size ratio ``r = R_large / R_small``, concentration of small grains ``c`` by number or
by volume, realisation ``s``): the isotropic protocol (``pardem.protocols.isotropic.sweep``: a random
gas compressed by the servo to static equilibrium at ``p0``, then the affine and relaxed moduli)
with ``n`` grains of the two radii whose number-mean radius is ``mean_radius``, and the gas seed
``sample.seed + s`` (common random numbers: realisation ``s`` of every point starts from the same
draws, so the trends between points are less noisy than the scatter). Then, from the final state:

* coordination ``Z`` and ``Z_no_rattlers`` (grains with fewer than ``dim + 1`` contacts removed,
  repeatedly), the rattler fraction;
* solid fraction (with the overlap correction, from the protocol);
* the fabric tensor ``<n n>`` of the force-carrying contacts between non-rattlers, and its
  anisotropy ``a`` (``pardem.physics.structure.fabric_anisotropy``);
* an order parameter: ``|<psi_6>|`` (hexatic, 2D) or the Steinhardt ``Q_6`` (3D) of the contact
  network (``order``), and its local form ``order_local``: ``<|psi_6|>`` over the grains, or the
  mean ``q_6`` per grain (crystallites of different orientations lower the global one only);
* the pair distribution ``g(r)`` (r in mean diameters) and its small-small, small-large and
  large-large parts;
* the distribution of normal contact forces ``f / <f>`` and its moments;
* the elastic moduli K and mu, affine and relaxed.

Ratio 1 is one monodisperse point (every concentration gives the same grains), so a plan keeps
it once, at c = 0. The cases are spread over the ranks of the job (``pardem.parallel.task_farm``),
each alone on its rank, so the results do not depend on the number of ranks.
"""
import copy
import time
from dataclasses import asdict, dataclass

import numpy as np

from pardem.physics import structure
from pardem.protocols import isotropic as iso
from pardem.engine.packing import contact_forces

# the scalar measures of a case, averaged per point over the realisations
MEASURES = ("pressure", "Z", "Z_no_rattlers", "rattler_fraction", "solid_fraction", "fabric_anisotropy",
            "order", "order_local", "K_affine", "K_relaxed", "mu_affine", "mu_relaxed", "mean_overlap_ratio")
UNITS = {"pressure": "Pa", "K_affine": "Pa", "K_relaxed": "Pa", "mu_affine": "Pa", "mu_relaxed": "Pa"}
G_BINS = 100                 # bins of g(r)
G_RANGE = 5.0                # g(r) up to 5 mean diameters (or half the smallest cell edge)
FORCE_EDGES = np.linspace(0.0, 5.0, 26)    # f / <f>


@dataclass(frozen=True)
class Plan:
    """What the study runs: ``ratios`` (R_large / R_small >= 1), ``concentrations`` of the small
    grains in [0, 1] by ``basis`` ("number" or "volume": area in 2D), ``realisations`` per point,
    the pressure ``pressure`` [Pa], the number-mean radius ``mean_radius`` [m], ``n`` grains,
    ``dimension`` 2 or 3, the first gas seed ``seed``."""
    ratios: tuple
    concentrations: tuple
    basis: str
    realisations: int
    pressure: float
    mean_radius: float
    n: int
    dimension: int
    seed: int

    def points(self):
        """The (ratio, concentration) points: ratio 1 once, at concentration 0."""
        out = []
        for r in self.ratios:
            for c in ((0.0,) if r == 1.0 else self.concentrations):
                out.append((float(r), float(c)))
        return out

    def cases(self):
        """Every case: dicts of ``ratio``, ``concentration``, ``realisation``, point by point."""
        return [{"ratio": r, "concentration": c, "realisation": s}
                for r, c in self.points() for s in range(self.realisations)]


def case_id(case):
    return f"r{case['ratio']:.6g}-c{case['concentration']:.6g}-s{case['realisation']}"


def sizes(plan, case):
    """The case's ``structure.Bidisperse`` size set."""
    return structure.bidisperse(plan.n, case["ratio"], case["concentration"], basis=plan.basis,
                                mean_radius=plan.mean_radius, dim=plan.dimension)


def case_deck(deck, plan, case):
    """The isotropic deck of one case: its two species (a species without grains left out), its
    seed, the study's pressure."""
    d = copy.deepcopy(deck)
    spec = sizes(plan, case)
    species = [(spec.r_small, spec.n_small), (spec.r_large, spec.n_large)]
    species = [(r, k) for r, k in species if k > 0]
    d["sample"]["n"] = plan.n
    d["sample"]["radii"] = [float(r) for r, _ in species]
    d["sample"]["fractions"] = [float(k) for _, k in species]     # counts: round(n k / n) = k exactly
    d["sample"]["seed"] = plan.seed + int(case["realisation"])
    d["preparation"]["pressures"] = [float(plan.pressure)]
    d.setdefault("domain", {})["dimension"] = plan.dimension
    return d


def state_arrays(sim):
    """Positions [n, 3] and radii [n] by gid, and the touching contacts (gids ``i``, ``j``, branch
    vectors [n_c, 3] [m], normal forces [n_c] [N]) of a case run on one rank (gids 0 .. n-1)."""
    e = sim.elements
    n = e.n_owned
    gid = e.gid[:n]
    if not np.array_equal(np.sort(gid), np.arange(n)):
        raise ValueError("a mixture case must own all its grains, with gids 0 .. n-1")
    x, radius = np.empty((n, 3)), np.empty(n)
    x[gid], radius[gid] = e.x[:n], e.radius[:n]
    cf = contact_forces(sim)
    return x, radius, cf["gid_i"].astype(np.int64), cf["gid_j"].astype(np.int64), cf["branch"], cf["fn"]


def measure(sim, dim):
    """The structure of the final packing (see the module docstring); a dict of JSON-able values."""
    x, radius, i, j, branch, fn = state_arrays(sim)
    n = len(radius)
    coord = structure.coordination(n, i, j, fn, dim=dim)
    kept = coord["kept"]
    ik, jk, bk = i[kept], j[kept], branch[kept]
    if len(bk):
        F = structure.fabric_tensor(bk, dim=dim)
        a = float(structure.fabric_anisotropy(F)[0])
    else:
        F, a = np.full((dim, dim), np.nan), float("nan")
    if dim == 2:
        _, order, order_local = structure.hexatic_order(n, ik, jk, bk)
        order_name = "psi6"
    else:
        q, order = structure.steinhardt(n, ik, jk, bk)
        order_local = float(np.nanmean(q)) if np.any(np.isfinite(q)) else float("nan")
        order_name = "Q6"
    box = sim.cell.length[:dim]
    d_mean = 2.0 * float(radius.mean())
    r_max = min(G_RANGE * d_mean, 0.5 * float(np.min(box)) * (1.0 - 1e-9))
    species = (radius > radius.min() * (1.0 + 1e-9)).astype(np.int64)     # 0 small, 1 large
    g = structure.pair_distribution(x, box, r_max, n_bins=G_BINS, dim=dim,
                                    species=species if species.max() > 0 else None)
    carried = fn[kept & (fn > 0)]
    if len(carried):
        forces = structure.force_distribution(carried, edges=FORCE_EDGES)
    else:   # no force at all: an unjammed packing (a preparation capped before it jammed)
        forces = {"edges": FORCE_EDGES, "density": np.full(len(FORCE_EDGES) - 1, np.nan),
                  "moments": {k: float("nan") for k in (2, 3, 4)}, "mean": float("nan")}
    out = {"Z": coord["Z"], "Z_no_rattlers": coord["Z_no_rattlers"], "rattlers": int(coord["rattlers"]),
           "rattler_fraction": coord["rattler_fraction"], "n_contacts": int(coord["n_contacts"]),
           "fabric": np.asarray(F).tolist(), "fabric_anisotropy": a, "order_name": order_name, "order": float(order),
           "order_local": float(order_local),
           "g_r": {"r_over_d": (g["r"] / d_mean).tolist(), "g": g["g"].tolist(),
                   "partial": {f"{p[0]}{p[1]}": v.tolist() for p, v in g.get("partial", {}).items()}},
           "forces": {"edges": np.asarray(forces["edges"]).tolist(),
                      "density": np.asarray(forces["density"]).tolist(),
                      "moments": {str(k): float(v) for k, v in forces["moments"].items()},
                      "mean_N": float(forces["mean"])}}
    return out


def run_case(comm, deck, plan, case, progress=None):
    """One case on ``comm`` (one rank): prepare, measure; returns its record (a dict)."""
    t0 = time.perf_counter()
    d = case_deck(deck, plan, case)
    spec = sizes(plan, case)
    rows, details, packing = iso.sweep(comm, d, d["preparation"]["pressures"], progress=progress)
    row, det = rows[0], details[0]
    rec = {"id": case_id(case), **case, "n": plan.n, "n_small": spec.n_small, "n_large": spec.n_large,
           "number_concentration": spec.number_concentration,
           "volume_concentration": spec.volume_concentration,
           "r_small": spec.r_small, "r_large": spec.r_large,
           "status": "ok" if det["converged"] else "not_converged", "steps": det["steps"],
           "pressure": row["p"], "solid_fraction": row["solid_fraction"],
           "mean_overlap_ratio": det["mean_overlap_ratio"],
           **{k: row[k] for k in ("K_affine", "K_relaxed", "mu_affine", "mu_relaxed")}}
    rec.update(measure(packing.sim, plan.dimension))
    rec["seconds"] = time.perf_counter() - t0
    return rec


def _stats(values):
    v = np.array([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if not len(v):
        return None, None
    return float(v.mean()), (float(v.std(ddof=1)) if len(v) > 1 else 0.0)


def summarise(records, plan):
    """Per point: the mean and sample standard deviation (ddof = 1) of every ``MEASURES`` over its
    realisations whose preparation converged, the mean g(r) and force density; ``n_failed``."""
    rows = []
    for r, c in plan.points():
        mine = [q for q in records if q["ratio"] == r and q["concentration"] == c]
        ok = [q for q in mine if q["status"] == "ok"]
        row = {"ratio": r, "concentration": c, "basis": plan.basis, "n_realisations": len(ok),
               "n_failed": len(mine) - len(ok)}
        if mine:
            row["number_concentration"] = mine[0]["number_concentration"]
            row["volume_concentration"] = mine[0]["volume_concentration"]
        for k in MEASURES:
            row[f"{k}_mean"], row[f"{k}_std"] = _stats(q.get(k) for q in ok)
        if ok:
            row["g_r"] = {"r_over_d": ok[0]["g_r"]["r_over_d"],
                          "g": np.mean([q["g_r"]["g"] for q in ok], axis=0).tolist()}
            row["force_density"] = {"edges": ok[0]["forces"]["edges"],
                                    "density": np.mean([q["forces"]["density"] for q in ok], axis=0).tolist()}
        rows.append(row)
    return {"plan": asdict(plan), "order_parameter": "psi6" if plan.dimension == 2 else "Q6", "points": rows,
            "units": UNITS}


def format_table(summary):
    """The printed table: one line per point, means and standard deviations."""
    order = summary["order_parameter"]
    head = (f"{'R_l/R_s':>7} {'c_small':>7} {'n':>3} {'Z':>13} {'Z w/o ratt.':>13} {'phi':>15} "
            f"{order:>13} {'K_rel [MPa]':>15} {'mu_rel [MPa]':>15}")
    lines = [head]

    def pm(row, k, scale=1.0, digits=3):
        m, s = row[f"{k}_mean"], row[f"{k}_std"]
        return "n/a" if m is None else f"{m / scale:.{digits}f}+-{s / scale:.{digits}f}"
    for row in summary["points"]:
        lines.append(f"{row['ratio']:>7.3g} {row['concentration']:>7.3g} {row['n_realisations']:>3d} "
                     f"{pm(row, 'Z'):>13} {pm(row, 'Z_no_rattlers'):>13} {pm(row, 'solid_fraction', digits=4):>15} "
                     f"{pm(row, 'order'):>13} {pm(row, 'K_relaxed', 1e6, 1):>15} {pm(row, 'mu_relaxed', 1e6, 1):>15}")
    return "\n".join(lines)
