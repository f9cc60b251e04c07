"""Structure of granular packings: fabric, coordination and rattlers, solid fraction, bond order,
pair distribution, contact-force distribution, bidisperse size specifications.

Pure functions over arrays (NumPy, Numba for the loops over pairs and grains); no MPI, no files.
A protocol gathers the contact network (or the positions) and calls them.

Conventions
-----------
* Units SI. Positions ``x`` [n, 3] [m]; in 2D (``dim=2``) the centres lie in the plane z = 0 and the
  z components of positions and branch vectors are ignored.
* A pair list is ``i``, ``j`` [n_pairs] int (rows, ``i != j``, each unordered pair once) and
  ``branch`` [n_pairs, 3] [m], the vector from the centre of i to the centre of j (periodic image
  included: ``x[j] - x[i] + shift``). Contacts of the engine and the output of ``neighbour_pairs`` /
  ``overlapping_pairs`` have this form.
* ``box``: None (no periodicity) or the lengths [m] of the orthorhombic periodic cell, ``dim`` or 3
  entries; every in-plane axis (x, y in 2D; x, y, z in 3D) is then periodic. Positions may be
  wrapped or not (up to 63 periods away, see ``pardem.physics.neighbours``).
* Bad arguments raise ``ValueError`` naming the argument and its allowed range (a protocol turns it
  into a deck error before any work).

Definitions
-----------
* Fabric tensor ``F = <n n>`` over the contact normals ``n = branch / |branch|`` ([dim, dim],
  trace 1); deviator ``D = F - I / dim``; anisotropy tensor ``a = dim (dim + 2) / 2 D``, the
  coefficient of the second-order expansion of the normal density ``E(n) = (1 + a_ij n_i n_j) /
  |S|`` (|S| = 2 pi in 2D, 4 pi in 3D); scalar anisotropy ``a = sqrt(a_ij a_ij / 2)`` in 2D (so
  that ``E(theta) = (1 + a cos 2 (theta - theta_0)) / 2 pi``) and ``sqrt(2/3 a_ij a_ij)`` in 3D
  (so that the axisymmetric ``E = (1 + a P_2(cos theta)) / 4 pi`` gives ``a``).
* Coordination ``Z = 2 N_c / N`` over force-carrying contacts (``fn > 0`` when forces are given);
  rattlers: grains with fewer than ``dim + 1`` force-carrying contacts, removed with their contacts
  repeatedly until none is left (the result, the (dim+1)-core of the contact graph, does not depend
  on the removal order); ``Z_no_rattlers = 2 N_c' / N'`` over the remaining grains and contacts.
* Solid fraction: grain volumes (3D spheres) or areas (2D disks of the spheres' radii, the
  sections by the plane z = 0) minus the overlap of each listed pair (3D lens volume, 2D lens area
  = the two circular segments), over the cell volume (3D) or area ``L_x L_y`` (2D). Overlaps of
  three or more grains are counted more than once (negligible at DEM overlaps).
* Hexatic order (2D): ``psi_m(k) = (1/n_k) sum_j exp(i m theta_kj)`` over the neighbours of k
  (``m = 6``); global ``|<psi_m>|``, the modulus of the mean over grains with at least one neighbour.
* Steinhardt order (3D): ``q_lm(k) = (1/n_k) sum_j Y_lm(r_kj)``,
  ``q_l(k) = sqrt(4 pi / (2l+1) sum_m |q_lm(k)|^2)``; global ``Q_l`` the same with ``q_lm``
  averaged over all bonds (Steinhardt, Nelson & Ronchetti 1983). Perfect crystals with their first
  shell: FCC Q4 = 0.19094, Q6 = 0.57452; HCP Q6 = 0.48476; BCC (8) Q6 = 0.51069; SC Q4 = 0.76376,
  Q6 = 0.35355.
* Pair distribution ``g(r)``: pair counts per shell over the ideal-gas count
  ``N (N - 1) / 2 * shell / V`` (V the cell volume, area in 2D), so an ideal gas of N points gives
  1 in expectation for ``r < min(L) / 2``.
* Bidisperse: ``size_ratio = R_large / R_small >= 1``; number concentration of small grains
  ``x_s = N_s / N``; volume concentration ``c_s = N_s R_s^dim / (N_s R_s^dim + N_l R_l^dim)``
  (an area concentration in 2D).
"""
from dataclasses import dataclass

import numpy as np
from numba import njit

from pardem.physics.neighbours import build_pairs


# -- checks ---------------------------------------------------------------------------------------

def _check_dim(dim):
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    return int(dim)


def _box(box, dim):
    """Periodic lengths [3] (0 along non-periodic axes) and the periodic flags, from ``box``."""
    if box is None:
        return np.zeros(3), (False, False, False)
    b = np.asarray(box, dtype=np.float64).ravel()
    if b.shape[0] not in (dim, 3):
        raise ValueError(f"box must hold {dim} or 3 lengths, got {b.shape[0]}")
    if not np.all(b[:dim] > 0.0) or not np.all(np.isfinite(b[:dim])):
        raise ValueError(f"box lengths must be finite and > 0, got {b[:dim]}")
    L = np.zeros(3)
    L[:dim] = b[:dim]
    return L, tuple(d < dim for d in range(3))


def _pairs(i, j, branch=None, n=None):
    i = np.ascontiguousarray(i, dtype=np.int64).ravel()
    j = np.ascontiguousarray(j, dtype=np.int64).ravel()
    if i.shape != j.shape:
        raise ValueError(f"i and j must have the same length, got {i.shape[0]} and {j.shape[0]}")
    if n is not None and i.shape[0] and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= n):
        raise ValueError(f"pair rows must lie in [0, {n}), got [{min(i.min(), j.min())}, "
                         f"{max(i.max(), j.max())}]")
    if np.any(i == j):
        raise ValueError("a pair joins a row with itself (i == j)")
    if branch is None:
        return i, j
    b = np.ascontiguousarray(branch, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 3 or b.shape[0] != i.shape[0]:
        raise ValueError(f"branch must have shape [{i.shape[0]}, 3], got {b.shape}")
    return i, j, b


def _plane(v, dim):
    """Copy of ``v`` [n, 3] with z zeroed in 2D."""
    v = np.array(v, dtype=np.float64)
    if dim == 2:
        v[:, 2] = 0.0
    return v


# -- pair lists -----------------------------------------------------------------------------------

def neighbour_pairs(x, cutoff, box=None, dim=3):
    """Pairs of centres closer than ``cutoff`` [m] (minimum image in a periodic ``box``).

    Returns ``i``, ``j`` [n_pairs] int64 (``i < j``) and ``branch`` [n_pairs, 3] [m]. A periodic
    box needs ``L >= 2 cutoff`` along each periodic axis (one image per pair).
    """
    dim = _check_dim(dim)
    if not (np.isfinite(cutoff) and cutoff > 0.0):
        raise ValueError(f"cutoff must be finite and > 0, got {cutoff}")
    x = _plane(np.atleast_2d(x), dim)
    return _search(x, np.zeros(x.shape[0]), float(cutoff), box, dim)


def overlapping_pairs(x, radius, box=None, dim=3):
    """Pairs whose spheres overlap, ``|branch| < R_i + R_j``: ``i``, ``j`` [n_pairs] int64 and
    ``branch`` [n_pairs, 3] [m] (see ``neighbour_pairs``)."""
    dim = _check_dim(dim)
    x = _plane(np.atleast_2d(x), dim)
    r = np.ascontiguousarray(radius, dtype=np.float64)
    if r.shape != (x.shape[0],) or not np.all(r > 0.0):
        raise ValueError(f"radius must hold {x.shape[0]} values > 0")
    return _search(x, r, 0.0, box, dim)


def _raw_search(x, radius, skin, box, dim, capacity=None):
    """``build_pairs`` over all rows: ``(pairs [n_p, 2] int32, shifts [n_p, 3] int8, L [3])``."""
    n = x.shape[0]
    L, periodic = _box(box, dim)
    if n < 2:
        return np.empty((0, 2), np.int32), np.empty((0, 3), np.int8), L
    pairs, shifts = build_pairs(x, radius, np.arange(n, dtype=np.int64), n, n, skin,
                                box_lo=np.zeros(3), box_hi=L, periodic=periodic, capacity=capacity)
    return pairs, shifts, L


def _search(x, radius, skin, box, dim):
    pairs, shifts, L = _raw_search(x, radius, skin, box, dim)
    i = pairs[:, 0].astype(np.int64)
    j = pairs[:, 1].astype(np.int64)
    branch = (x[j] - x[i]) + shifts * L
    return i, j, branch


# -- fabric ---------------------------------------------------------------------------------------

def fabric_tensor(branch, dim=3, weights=None):
    """Fabric tensor ``<n n>`` [dim, dim] of the directions of ``branch`` [n_c, 3] (any length > 0).

    ``weights`` [n_c] >= 0 (optional) gives ``sum w n n / sum w``, e.g. ``w = f_n`` for the
    force-weighted fabric; select contacts (force-carrying, no rattlers) by indexing ``branch``.
    """
    dim = _check_dim(dim)
    b = np.atleast_2d(np.asarray(branch, dtype=np.float64))[:, :dim]
    if b.shape[0] == 0:
        raise ValueError("fabric_tensor needs at least one contact")
    norm = np.sqrt(np.einsum("ka,ka->k", b, b))
    if not np.all(norm > 0.0):
        raise ValueError("branch vectors must have a length > 0")
    u = b / norm[:, None]
    if weights is None:
        return u.T @ u / b.shape[0]
    w = np.asarray(weights, dtype=np.float64).ravel()
    if w.shape[0] != b.shape[0] or not np.all(w >= 0.0) or not w.sum() > 0.0:
        raise ValueError(f"weights must hold {b.shape[0]} values >= 0 with a positive sum")
    return (u * w[:, None]).T @ u / w.sum()


def fabric_deviator(F):
    """Deviator ``F - tr(F) / dim I`` of a fabric tensor [dim, dim]."""
    F = np.asarray(F, dtype=np.float64)
    return F - np.trace(F) / F.shape[0] * np.eye(F.shape[0])


def fabric_anisotropy(F):
    """Anisotropy of a fabric tensor [dim, dim]: ``(a, a_ij, direction)``.

    ``a_ij = dim (dim + 2) / 2 * deviator`` is the second-order coefficient of the normal density,
    ``a`` its scalar magnitude (module docstring: the ``a`` of ``1 + a cos 2(theta - theta_0)`` in
    2D, of ``1 + a P_2(cos theta)`` in 3D) and ``direction`` [dim] the unit major principal
    direction of F.
    """
    F = np.asarray(F, dtype=np.float64)
    dim = _check_dim(F.shape[0])
    aij = 0.5 * dim * (dim + 2) * fabric_deviator(F)
    c = 0.5 if dim == 2 else 2.0 / 3.0
    w, v = np.linalg.eigh(0.5 * (F + F.T))
    return float(np.sqrt(c * np.sum(aij * aij))), aij, v[:, np.argmax(w)]


# -- coordination and rattlers --------------------------------------------------------------------

@njit(cache=True)
def _core(n, i, j, live, k):
    """Masks of the k-core: grains ``[n]`` and pairs ``[n_pairs]`` left after repeatedly removing
    grains with fewer than k live pairs. ``live`` [n_pairs] bool: the pairs that count."""
    m = i.shape[0]
    deg = np.zeros(n, np.int64)
    start = np.zeros(n + 1, np.int64)
    for p in range(m):
        if live[p]:
            deg[i[p]] += 1
            deg[j[p]] += 1
    for a in range(n):
        start[a + 1] = start[a] + deg[a]
    cursor = start[:n].copy()
    inc = np.empty(start[n], np.int64)   # incident live pairs of each grain (CSR)
    for p in range(m):
        if live[p]:
            inc[cursor[i[p]]] = p
            cursor[i[p]] += 1
            inc[cursor[j[p]]] = p
            cursor[j[p]] += 1
    alive = np.ones(n, np.bool_)
    kept = live.copy()
    stack = np.empty(n, np.int64)
    queued = np.zeros(n, np.bool_)
    top = 0
    for a in range(n):
        if deg[a] < k:
            stack[top] = a
            top += 1
            queued[a] = True
    while top > 0:
        top -= 1
        a = stack[top]
        alive[a] = False
        for q in range(start[a], start[a + 1]):
            p = inc[q]
            if not kept[p]:
                continue
            kept[p] = False
            b = j[p] if i[p] == a else i[p]
            deg[b] -= 1
            if deg[b] < k and not queued[b]:
                stack[top] = b
                top += 1
                queued[b] = True
    return alive, kept


def rattlers(n, i, j, fn=None, dim=3):
    """Rattler removal: ``(alive, kept)``, masks [n] of the non-rattlers and [n_pairs] of the
    force-carrying contacts between them. Force-carrying: ``fn > 0`` when ``fn`` [n_pairs] [N] is
    given, else every listed pair. A grain with fewer than ``dim + 1`` such contacts is a rattler;
    removals repeat until none is left."""
    dim = _check_dim(dim)
    n = int(n)
    i, j = _pairs(i, j, n=n)
    if fn is None:
        live = np.ones(i.shape[0], np.bool_)
    else:
        fn = np.asarray(fn, dtype=np.float64).ravel()
        if fn.shape != i.shape:
            raise ValueError(f"fn must hold {i.shape[0]} values, got {fn.shape[0]}")
        live = fn > 0.0
    return _core(n, i, j, live, dim + 1)


def coordination(n, i, j, fn=None, dim=3):
    """Coordination numbers of a contact network of ``n`` grains (module docstring).

    Returns a dict: ``Z`` = 2 N_c / N (force-carrying contacts), ``Z_no_rattlers`` = 2 N_c' / N'
    (0 when every grain is a rattler), ``rattlers`` (count), ``rattler_fraction`` = rattlers / N,
    ``n_contacts`` = N_c, ``alive`` [n] and ``kept`` [n_pairs] (masks of ``rattlers``).
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    alive, kept = rattlers(n, i, j, fn, dim)
    nc = int(len(i)) if fn is None else int(np.count_nonzero(np.asarray(fn) > 0.0))
    n_alive = int(alive.sum())
    return {"Z": 2.0 * nc / n,
            "Z_no_rattlers": 2.0 * int(kept.sum()) / n_alive if n_alive else 0.0,
            "rattlers": n - n_alive, "rattler_fraction": (n - n_alive) / n, "n_contacts": nc,
            "alive": alive, "kept": kept}


# -- solid fraction -------------------------------------------------------------------------------

@njit(cache=True)
def _segment(t):
    """``t - sin(t) cos(t)`` (twice the area of a unit circle's segment of half-angle t), with a
    series for small t where the difference cancels (relative error < 1e-15 at t = 1e-2)."""
    if t < 1e-2:
        t2 = t * t
        return t * t2 * (2.0 / 3.0 - t2 * (2.0 / 15.0 - t2 * (4.0 / 315.0)))
    return t - np.sin(t) * np.cos(t)


@njit(cache=True)
def lens_area(r1, r2, d):
    """Area [m^2] shared by two disks of radii r1, r2 [m] at centre distance d [m]: the sum of the
    two circular segments ``r^2 (t - sin t cos t)`` cut by the common chord (half-angles t from
    atan2, well conditioned at small overlaps); the smaller disk's area when one contains the
    other, 0 when they do not overlap."""
    delta = (r1 + r2) - d
    if delta <= 0.0:
        return 0.0
    if d <= abs(r1 - r2):
        rm = min(r1, r2)
        return np.pi * rm * rm
    # (2 d h)^2 with h the half chord (Heron), written with the overlap delta so nothing cancels
    q = delta * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)
    h2d = np.sqrt(max(q, 0.0))
    a1 = d * d + r1 * r1 - r2 * r2   # 2 d times the distance from centre 1 to the chord
    a2 = d * d + r2 * r2 - r1 * r1
    t1 = np.arctan2(h2d, a1)
    t2 = np.arctan2(h2d, a2)
    return r1 * r1 * _segment(t1) + r2 * r2 * _segment(t2)


@njit(cache=True)
def lens_volume(r1, r2, d):
    """Volume [m^3] shared by two spheres: ``pi (r1 + r2 - d)^2 (d^2 + 2 d (r1 + r2) -
    3 (r1 - r2)^2) / (12 d)``; the smaller sphere's volume when one contains the other."""
    delta = (r1 + r2) - d
    if delta <= 0.0:
        return 0.0
    if d <= abs(r1 - r2):
        rm = min(r1, r2)
        return 4.0 / 3.0 * np.pi * rm * rm * rm
    return (np.pi * delta * delta * (d * d + 2.0 * d * (r1 + r2) - 3.0 * (r1 - r2) ** 2)
            / (12.0 * d))


@njit(cache=True)
def _overlaps(radius, i, j, dist, dim):
    s = 0.0
    for p in range(i.shape[0]):
        if dim == 2:
            s += lens_area(radius[i[p]], radius[j[p]], dist[p])
        else:
            s += lens_volume(radius[i[p]], radius[j[p]], dist[p])
    return s


def solid_fraction(radius, cell, dim=3, i=None, j=None, dist=None):
    """Solid fraction of grains of ``radius`` [n] [m] in a cell of lengths ``cell`` [dim or 3] [m].

    3D: sphere volumes over ``L_x L_y L_z``; 2D: disk areas over ``L_x L_y``; minus the overlap of
    each pair ``i``, ``j`` at centre distance ``dist`` [n_pairs] [m] (pairs that do not overlap add
    nothing; without pairs no correction). Returns ``(fraction, uncorrected)``.
    """
    dim = _check_dim(dim)
    r = np.ascontiguousarray(radius, dtype=np.float64).ravel()
    L, _ = _box(cell, dim)
    measure = float(np.prod(L[:dim]))
    solid = float(np.sum(np.pi * r**2) if dim == 2 else np.sum(4.0 / 3.0 * np.pi * r**3))
    over = 0.0
    if i is not None:
        i, j = _pairs(i, j, n=r.shape[0])
        dist = np.ascontiguousarray(dist, dtype=np.float64).ravel()
        if dist.shape != i.shape:
            raise ValueError(f"dist must hold {i.shape[0]} values, got {dist.shape[0]}")
        over = _overlaps(r, i, j, dist, dim)
    return (solid - over) / measure, solid / measure


# -- bond-orientational order ---------------------------------------------------------------------

@njit(cache=True)
def _psi_sums(i, j, branch, m, re, im, cnt):
    sign = 1.0 if m % 2 == 0 else -1.0   # the bond seen from j points the other way: e^{i m pi}
    for p in range(i.shape[0]):
        t = np.arctan2(branch[p, 1], branch[p, 0])
        c = np.cos(m * t)
        s = np.sin(m * t)
        a, b = i[p], j[p]
        re[a] += c
        im[a] += s
        re[b] += sign * c
        im[b] += sign * s
        cnt[a] += 1
        cnt[b] += 1


def hexatic_order(n, i, j, branch, m=6):
    """Bond-orientational order ``psi_m`` in the plane (m = 6: hexatic) of ``n`` grains.

    Neighbours: the pairs ``i``, ``j``, ``branch`` (contacts, or ``neighbour_pairs`` for a cutoff);
    only the x, y components of ``branch`` are used. Returns ``(psi, global_order, mean_modulus)``:
    ``psi`` [n] complex per grain (0 for a grain without neighbours), ``global_order = |<psi>|``
    and ``mean_modulus = <|psi|>``, both over the grains with at least one neighbour (NaN if none).
    """
    n = int(n)
    m = int(m)
    if m < 1:
        raise ValueError(f"m must be an integer >= 1, got {m}")
    i, j, b = _pairs(i, j, branch, n=n)
    re, im, cnt = np.zeros(n), np.zeros(n), np.zeros(n, np.int64)
    _psi_sums(i, j, b, m, re, im, cnt)
    has = cnt > 0
    psi = np.zeros(n, dtype=np.complex128)
    psi[has] = (re[has] + 1j * im[has]) / cnt[has]
    if not has.any():
        return psi, float("nan"), float("nan")
    return psi, float(abs(psi[has].mean())), float(np.abs(psi[has]).mean())


@njit(cache=True)
def legendre_normalised(l, m, x):
    """``sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!) P_l^m(x)`` (Condon-Shortley phase), 0 <= m <= l,
    |x| <= 1: ``Y_lm(theta, phi)`` is this at ``x = cos theta`` times ``e^{i m phi}``. Stable
    recurrence on the normalised functions (Numerical Recipes 3rd ed., section 6.7)."""
    pmm = 1.0
    omx2 = (1.0 - x) * (1.0 + x)
    fact = 1.0
    for _ in range(m):
        pmm *= omx2 * fact / (fact + 1.0)
        fact += 2.0
    pmm = np.sqrt((2 * m + 1) * pmm / (4.0 * np.pi))
    if m % 2 == 1:
        pmm = -pmm
    if l == m:
        return pmm
    pmmp1 = x * np.sqrt(2.0 * m + 3.0) * pmm
    if l == m + 1:
        return pmmp1
    oldfact = np.sqrt(2.0 * m + 3.0)
    pll = 0.0
    for ll in range(m + 2, l + 1):
        fact = np.sqrt((4.0 * ll * ll - 1.0) / (ll * ll - m * m))
        pll = (x * pmmp1 - pmm / oldfact) * fact
        oldfact = fact
        pmm = pmmp1
        pmmp1 = pll
    return pll


@njit(cache=True)
def _qlm_sums(i, j, branch, l, re, im, cnt):
    """Sums over the bonds of each grain of ``Y_lm`` (m = 0..l) into ``re``, ``im`` [n, l+1]."""
    sign = 1.0 if l % 2 == 0 else -1.0   # Y_lm(-r) = (-1)^l Y_lm(r)
    for p in range(i.shape[0]):
        bx, by, bz = branch[p, 0], branch[p, 1], branch[p, 2]
        r = np.sqrt(bx * bx + by * by + bz * bz)
        x = min(1.0, max(-1.0, bz / r))
        phi = np.arctan2(by, bx)
        a, b = i[p], j[p]
        for m in range(l + 1):
            y = legendre_normalised(l, m, x)
            c = y * np.cos(m * phi)
            s = y * np.sin(m * phi)
            re[a, m] += c
            im[a, m] += s
            re[b, m] += sign * c
            im[b, m] += sign * s
        cnt[a] += 1
        cnt[b] += 1


def _ql(re, im, l):
    """``sqrt(4 pi / (2l+1) sum_{m=-l..l} |q_lm|^2)`` from m >= 0 (|q_{l,-m}| = |q_lm|)."""
    w = np.full(l + 1, 2.0)
    w[0] = 1.0
    return np.sqrt(4.0 * np.pi / (2 * l + 1) * ((re * re + im * im) @ w))


def steinhardt(n, i, j, branch, l=6):
    """Steinhardt bond order ``q_l`` per grain and the global ``Q_l`` (module docstring) of ``n``
    grains with the neighbour pairs ``i``, ``j``, ``branch`` (contacts, or ``neighbour_pairs``).

    Returns ``(q, Q)``: ``q`` [n] (NaN for a grain without neighbours) and ``Q`` from the
    bond-averaged ``q_lm`` (NaN without bonds).
    """
    n = int(n)
    l = int(l)
    if l < 0:
        raise ValueError(f"l must be an integer >= 0, got {l}")
    i, j, b = _pairs(i, j, branch, n=n)
    if b.shape[0] and not np.all(np.einsum("ka,ka->k", b, b) > 0.0):
        raise ValueError("branch vectors must have a length > 0")
    re, im = np.zeros((n, l + 1)), np.zeros((n, l + 1))
    cnt = np.zeros(n, np.int64)
    _qlm_sums(i, j, b, l, re, im, cnt)
    q = np.full(n, np.nan)
    has = cnt > 0
    q[has] = _ql(re[has] / cnt[has, None], im[has] / cnt[has, None], l)
    total = cnt.sum()
    if total == 0:
        return q, float("nan")
    Q = _ql(re.sum(axis=0)[None, :] / total, im.sum(axis=0)[None, :] / total, l)[0]
    return q, float(Q)


# -- pair distribution ----------------------------------------------------------------------------

@njit(cache=True)
def _pair_bins(x, pairs, shifts, L, inv_dr, n_bins):
    """Bin index [n_pairs] of each pair's distance ``|x_j - x_i + shift L|`` (bins of 1 / inv_dr)."""
    k = np.empty(pairs.shape[0], np.int64)
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        d2 = 0.0
        for c in range(3):
            e = (x[b, c] - x[a, c]) + shifts[p, c] * L[c]
            d2 += e * e
        m = int(np.sqrt(d2) * inv_dr)
        k[p] = m if m < n_bins else n_bins - 1
    return k


def pair_distribution(x, box, r_max, n_bins=100, dim=3, species=None):
    """Pair distribution ``g(r)`` of the centres ``x`` [n, 3] in the periodic ``box``.

    Bins of width ``r_max / n_bins`` on ``[0, r_max)``, ``r_max <= min(L) / 2``. Returns a dict:
    ``r`` [n_bins] bin centres [m], ``edges`` [n_bins + 1], ``g`` [n_bins], ``counts`` (pairs per
    bin), ``expected`` (ideal-gas pairs per bin, ``N (N-1)/2 shell / V``); with ``species`` [n] int
    labels also ``partial[(a, b)]`` for a <= b: pair counts between a and b over their ideal-gas
    count (``N_a (N_a - 1) / 2`` or ``N_a N_b`` pairs, times shell / V).
    """
    dim = _check_dim(dim)
    x = _plane(np.atleast_2d(x), dim)
    n = x.shape[0]
    if n < 2:
        raise ValueError(f"pair_distribution needs at least 2 points, got {n}")
    L, _ = _box(box, dim)
    if not (np.isfinite(r_max) and 0.0 < r_max <= 0.5 * L[:dim].min()):
        raise ValueError(f"r_max must lie in (0, min(box) / 2 = {0.5 * L[:dim].min():.6g}], got {r_max}")
    n_bins = int(n_bins)
    if n_bins < 1:
        raise ValueError(f"n_bins must be >= 1, got {n_bins}")
    edges = np.linspace(0.0, r_max, n_bins + 1)
    shell = (np.pi * np.diff(edges**2) if dim == 2 else 4.0 / 3.0 * np.pi * np.diff(edges**3))
    V = float(np.prod(L[:dim]))
    expected = 0.5 * n * (n - 1) * shell / V
    # pairs at distances < r_max (the search's strict test); sized for a gas plus 30 %, so that a
    # dense packing rarely needs the neighbour search's second pass
    pairs, shifts, L = _raw_search(x, np.zeros(n), float(r_max), box, dim,
                                   capacity=int(1.3 * expected.sum()) + 16 * n)
    k = _pair_bins(x, pairs, shifts, L, n_bins / r_max, n_bins)
    counts = np.bincount(k, minlength=n_bins)
    out = {"r": 0.5 * (edges[1:] + edges[:-1]), "edges": edges, "g": counts / expected,
           "counts": counts, "expected": expected}
    if species is not None:
        s = np.asarray(species).ravel()
        if s.shape[0] != n:
            raise ValueError(f"species must hold {n} labels, got {s.shape[0]}")
        labels = np.unique(s)
        part = {}
        si, sj = s[pairs[:, 0]], s[pairs[:, 1]]
        for ia, a in enumerate(labels):
            na = int(np.count_nonzero(s == a))
            for bl in labels[ia:]:
                nb = int(np.count_nonzero(s == bl))
                sel = ((si == a) & (sj == bl)) | ((si == bl) & (sj == a))
                c = np.bincount(k[sel], minlength=n_bins)
                npairs = 0.5 * na * (na - 1) if a == bl else float(na * nb)
                with np.errstate(invalid="ignore", divide="ignore"):
                    part[(a.item(), bl.item())] = c / (npairs * shell / V)
        out["partial"] = part
    return out


# -- contact forces -------------------------------------------------------------------------------

def force_distribution(fn, edges=None, moments=(2, 3, 4)):
    """Distribution of the normal contact forces ``fn`` [n_c] [N] (only ``fn > 0`` counted).

    Returns a dict: ``mean`` <f> [N], ``n`` (forces counted), ``edges`` (of f / <f>; default 50
    bins on [0, 5]), ``density`` (probability density of f / <f>, normalised over the forces that
    fall in the bins: ``numpy.histogram(density=True)``), ``moments[k] = <(f / <f>)^k>``,
    ``fraction_above_mean``, ``fraction_beyond`` (forces beyond the last edge).
    """
    f = np.asarray(fn, dtype=np.float64).ravel()
    if not np.all(np.isfinite(f)):
        raise ValueError("fn must be finite")
    f = f[f > 0.0]
    if f.shape[0] == 0:
        raise ValueError("force_distribution needs at least one force > 0")
    edges = np.linspace(0.0, 5.0, 51) if edges is None else np.asarray(edges, dtype=np.float64)
    mean = float(f.mean())
    y = f / mean
    dens, _ = np.histogram(y, bins=edges, density=True)
    return {"mean": mean, "n": int(f.shape[0]), "edges": edges, "density": dens,
            "moments": {int(k): float(np.mean(y ** k)) for k in moments},
            "fraction_above_mean": float(np.mean(y > 1.0)),
            "fraction_beyond": float(np.mean(y >= edges[-1]))}


# -- bidisperse sizes -----------------------------------------------------------------------------

def _check_ratio_conc(size_ratio, c, name):
    if not (np.isfinite(size_ratio) and size_ratio >= 1.0):
        raise ValueError(f"size_ratio (R_large / R_small) must be >= 1, got {size_ratio}")
    if not (0.0 <= c <= 1.0):
        raise ValueError(f"{name} must lie in [0, 1], got {c}")


def number_to_volume_concentration(x_small, size_ratio, dim=3):
    """Volume (2D: area) concentration of small grains ``x / (x + (1 - x) r^dim)`` from their
    number concentration ``x_small``; ``r = size_ratio = R_large / R_small``."""
    dim = _check_dim(dim)
    _check_ratio_conc(size_ratio, x_small, "number concentration")
    return x_small / (x_small + (1.0 - x_small) * size_ratio**dim)


def volume_to_number_concentration(c_small, size_ratio, dim=3):
    """Number concentration of small grains ``c r^dim / (1 - c + c r^dim)`` from their volume (2D:
    area) concentration ``c_small``; the inverse of ``number_to_volume_concentration``."""
    dim = _check_dim(dim)
    _check_ratio_conc(size_ratio, c_small, "volume concentration")
    rd = size_ratio**dim
    return c_small * rd / (1.0 - c_small + c_small * rd)


@dataclass(frozen=True)
class Bidisperse:
    """A bidisperse size set: ``radii`` [n] [m] (the ``n_small`` small ones first), the two radii
    [m], the counts, the realised number and volume (2D: area) concentrations of small grains."""
    radii: np.ndarray
    r_small: float
    r_large: float
    n_small: int
    n_large: int
    number_concentration: float
    volume_concentration: float
    size_ratio: float
    dim: int


def bidisperse(n, size_ratio, concentration, basis="number", mean_radius=None, large_radius=None,
               dim=3):
    """Radii and counts of ``n`` grains of two sizes.

    ``size_ratio = R_large / R_small >= 1``; ``concentration`` of the small grains in [0, 1], by
    number (``basis="number"``) or by volume (``"volume"``; area in 2D, ``dim=2``). The count of
    small grains is the nearest integer to ``x_s n`` (x_s the number concentration); the size is
    set by exactly one of ``mean_radius`` (the number mean of the realised radii) or
    ``large_radius``. The returned concentrations are those of the realised counts.
    """
    dim = _check_dim(dim)
    n = int(n)
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if basis not in ("number", "volume"):
        raise ValueError(f"basis must be 'number' or 'volume', got {basis!r}")
    if (mean_radius is None) == (large_radius is None):
        raise ValueError("give exactly one of mean_radius and large_radius")
    size = mean_radius if large_radius is None else large_radius
    if not (np.isfinite(size) and size > 0.0):
        raise ValueError(f"{'mean_radius' if large_radius is None else 'large_radius'} must be > 0, "
                         f"got {size}")
    x = (concentration if basis == "number"
         else volume_to_number_concentration(concentration, size_ratio, dim))
    _check_ratio_conc(size_ratio, x, f"{basis} concentration")
    ns = int(np.floor(x * n + 0.5))
    nl = n - ns
    xs = ns / n
    if large_radius is None:
        rs = mean_radius / (xs + (1.0 - xs) * size_ratio)
    else:
        rs = large_radius / size_ratio
    rl = rs * size_ratio
    radii = np.concatenate([np.full(ns, rs), np.full(nl, rl)])
    return Bidisperse(radii=radii, r_small=float(rs), r_large=float(rl), n_small=ns, n_large=nl,
                      number_concentration=xs,
                      volume_concentration=number_to_volume_concentration(xs, size_ratio, dim),
                      size_ratio=float(size_ratio), dim=dim)
