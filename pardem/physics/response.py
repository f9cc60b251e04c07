"""The point-load response of a 2D packing from its contact forces: per-grain stress moments,
their change from a reference state, binning into layers and x bins, profile widths. Pure
functions over arrays (no MPI, no files); ``pardem.protocols.response`` gathers the arrays.

**Per-grain moment** (Love-Weber): ``M_i = sum_c a_ic n_c (x) f_c`` [N m] over the contacts c of
grain i, with ``f_c`` the force on i, ``n_c`` the unit normal from i to its partner, and the
contact point at ``a_ic = R_i - delta / 2`` from the centre of i (``a_i + a_j`` = the centre
distance). Summed over the grains, ``sum_i M_i = sum_c d_c (x) f_c`` is the cell's Love-Weber sum,
so ``sum_i M_i / (L_x L_y t)`` is pardem's 2D stress (tension positive, ``t`` the thickness of the
stress convention). The stress of a region is ``sum_{i in region} M_i / (area t)``.

**Response** (``moment_change``): ``dM_i = sum_c a_ic^0 n_c^0 (x) (f_c - f_c^0)``: the arms of the
reference state (superscript 0) times the change of the contact forces, pairs matched by their gid
pair (a pair present in one state only has zero force in the other and takes that state's arm).
It is the linear response (the difference of the full moments differs from it by the reference
forces times the change of the arms, a term of relative order ``delta / d``), and it obeys force
balance exactly: for a band B of grains between the heights ``Y1 < Y2`` whose grains carry no
external load, static equilibrium of every grain gives ``sum_{i in B} dM_i,yy = sum_{c crossing}
y_c^0 df_c,y`` (the contacts inside B cancel, their two arms meeting at the same contact point);
when every contact crossing the band's faces has its reference contact point on a face (a
triangular lattice with bands centred on its rows), this is ``-(Y2 - Y1) dT`` with ``dT`` the
extra vertical force transmitted downwards through the band. So the band's mean stress change is
``-dT / (L_x t)``, and the binned profile integrates to ``int dsigma_yy dx = -dT / t`` at every
depth: ``-F / t`` when all of the extra force F goes down (Flamant's ``int sigma_zz dx = -P``,
``P = F / t``). In a disordered packing the contact points scatter about the faces and the
identity holds on average over bands (the protocol reports the ratio per layer).

Units: positions and lengths [m], forces [N], moments [N m], stresses [Pa].
"""
import numpy as np




def contact_arms(dist, radius_i, radius_j):
    """Distances [m] from each centre to the contact point, ``(a_i, a_j)`` [n_c] each:
    ``a_i = R_i - delta / 2 = (dist + R_i - R_j) / 2`` (``delta = R_i + R_j - dist``)."""
    d = np.asarray(dist, dtype=np.float64)
    ri = np.asarray(radius_i, dtype=np.float64)
    rj = np.asarray(radius_j, dtype=np.float64)
    return 0.5 * (d + ri - rj), 0.5 * (d + rj - ri)


def grain_moments(n_grains, gid_i, gid_j, normal, arm_i, arm_j, force):
    """``M`` [n_grains, 3, 3] [N m] (module docstring) from the contacts: gids [n_c] (grains are
    indexed by gid 0 .. n_grains - 1), unit normals from i to j [n_c, 3], arms [n_c] [m], force on
    i [n_c, 3] [N]. ``M[k, a, b] = sum a n_a f_b``."""
    n = np.asarray(normal, dtype=np.float64)
    f = np.asarray(force, dtype=np.float64)
    nf = n[:, :, None] * f[:, None, :]
    M = np.zeros((int(n_grains), 3, 3))
    np.add.at(M, np.asarray(gid_i, dtype=np.int64), np.asarray(arm_i)[:, None, None] * nf)
    # on j: arm -n a_j, force -f: the same sign
    np.add.at(M, np.asarray(gid_j, dtype=np.int64), np.asarray(arm_j)[:, None, None] * nf)
    return M


def _keys(c):
    return np.asarray(c["gid_i"], dtype=np.int64) * (np.int64(1) << np.int64(31)) + \
        np.asarray(c["gid_j"], dtype=np.int64)


def moment_change(n_grains, reference, current):
    """``dM`` [n_grains, 3, 3] [N m]: the reference arms times the change of the contact forces
    (module docstring). ``reference``, ``current``: dicts of contact arrays ``gid_i, gid_j``
    [n_c] (``gid_i < gid_j``), ``normal`` [n_c, 3], ``arm_i, arm_j`` [n_c] [m], ``force`` [n_c, 3]
    [N] (on i), each pair once."""
    k0, k1 = _keys(reference), _keys(current)
    for name, k in (("reference", k0), ("current", k1)):
        if len(np.unique(k)) != len(k):
            raise ValueError(f"{name}: a contact pair is listed twice (each pair once)")
    both, i0, i1 = np.intersect1d(k0, k1, assume_unique=True, return_indices=True)
    only0 = np.setdiff1d(np.arange(len(k0)), i0)
    only1 = np.setdiff1d(np.arange(len(k1)), i1)
    f0 = np.asarray(reference["force"], dtype=np.float64)
    f1 = np.asarray(current["force"], dtype=np.float64)
    parts = []
    # pairs in both states: reference geometry, force change
    parts.append((reference, i0, f1[i1] - f0[i0]))
    # lost pairs: reference geometry, force -f0; new pairs: current geometry, force f1
    parts.append((reference, only0, -f0[only0]))
    parts.append((current, only1, f1[only1]))
    dM = np.zeros((int(n_grains), 3, 3))
    for src, rows, df in parts:
        if len(rows):
            dM += grain_moments(n_grains, np.asarray(src["gid_i"])[rows], np.asarray(src["gid_j"])[rows],
                                np.asarray(src["normal"])[rows], np.asarray(src["arm_i"])[rows],
                                np.asarray(src["arm_j"])[rows], df)
    return dM


def relative_x(x, x0, period):
    """Horizontal offsets [m] of ``x`` from ``x0`` in a cell periodic along x with ``period`` [m],
    in ``[-period / 2, period / 2)``."""
    L = float(period)
    return np.mod(np.asarray(x, dtype=np.float64) - float(x0) + 0.5 * L, L) - 0.5 * L


def bin_stress(x, depth, values, x_edges, z_edges, thickness):
    """Binned stress [Pa] [nz, nx]: ``sum values / (dx dz t)`` of the grains whose ``x`` [n] and
    ``depth`` [n] [m] fall in each bin of ``x_edges`` [nx + 1], ``z_edges`` [nz + 1] [m];
    ``values`` [n] per-grain moments [N m] (e.g. ``dM_yy``); grains outside the edges are left
    out. Also returns the grain count per bin [nz, nx]."""
    xe = np.asarray(x_edges, dtype=np.float64)
    ze = np.asarray(z_edges, dtype=np.float64)
    s, _, _ = np.histogram2d(depth, x, bins=(ze, xe), weights=values)
    c, _, _ = np.histogram2d(depth, x, bins=(ze, xe))
    area = np.diff(ze)[:, None] * np.diff(xe)[None, :]
    return s / (area * float(thickness)), c.astype(np.int64)


def layer_force(depth, values, z_edges):
    """``-sum_{layer} dM_yy / h`` [N] per layer [nz] (``h`` its height): the extra vertical force
    transmitted downwards through each layer (module docstring; exact for bands whose faces carry
    the contact points)."""
    ze = np.asarray(z_edges, dtype=np.float64)
    s, _ = np.histogram(depth, bins=ze, weights=values)
    return -s / np.diff(ze)


def widths(x, profile):
    """``(second-moment width, half width at half maximum)`` [m] of a profile [nx] (a stress,
    e.g. ``-sigma_zz``, > 0 near the load) over the abscissae ``x`` [nx] [m] centred on the load.
    The second moment uses the positive part of the profile; the half width is interpolated
    linearly on each side of the maximum and averaged (None if the profile never falls to half)."""
    x = np.asarray(x, dtype=np.float64)
    w = np.clip(np.asarray(profile, dtype=np.float64), 0.0, None)
    if not w.sum() > 0.0:
        return None, None
    second = float(np.sqrt((w * x * x).sum() / w.sum()))
    k = int(np.argmax(w))
    half = 0.5 * w[k]
    sides = []
    for step in (1, -1):
        j = k
        while 0 <= j + step < len(w) and w[j + step] > half:
            j += step
        if not 0 <= j + step < len(w):
            return second, None
        a, b = w[j], w[j + step]
        xh = x[j] + (x[j + step] - x[j]) * (a - half) / (a - b)
        sides.append(abs(xh))
    return second, float(0.5 * (sides[0] + sides[1]))


def fit_widths(depth, width):
    """Least-squares fits of the width [m] against depth [m]: elastic ``w = c z`` and diffusive
    ``w = sqrt(2 D z)`` (``w^2 = 2 D z``): dict with ``c``, ``D`` [m], and the r.m.s. relative
    residual of each."""
    z = np.asarray(depth, dtype=np.float64)
    w = np.asarray(width, dtype=np.float64)
    ok = np.isfinite(w) & (w > 0) & (z > 0)
    z, w = z[ok], w[ok]
    if len(z) < 2:
        return {"c": None, "D": None, "elastic_residual": None, "diffusive_residual": None}
    c = float((z * w).sum() / (z * z).sum())
    D = float((z * w * w).sum() / (2.0 * (z * z).sum()))
    res_e = float(np.sqrt(np.mean((c * z / w - 1.0) ** 2)))
    res_d = float(np.sqrt(np.mean((np.sqrt(2.0 * D * z) / w - 1.0) ** 2)))
    return {"c": c, "D": D, "elastic_residual": res_e, "diffusive_residual": res_d}


def diffusive_width(depth, D):
    """``sqrt(2 D z)`` [m]: the width of a diffusive profile at depth z [m] (``D`` [m])."""
    return np.sqrt(2.0 * float(D) * np.asarray(depth, dtype=np.float64))


__all__ = ["contact_arms", "grain_moments", "moment_change", "relative_x", "bin_stress", "layer_force",
           "widths", "fit_widths", "diffusive_width"]
