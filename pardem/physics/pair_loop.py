"""The pair loops shared by every sphere-sphere contact law (docs/physics.md section 8).

A law supplies two inline Numba functions, chosen at setup by the law's ``pair_function(params)``
(sub-models such as damping or cement are compile-time constants of those functions, never a
branch on strings in the loop):

* ``engaged(p, hist, dist2, rsum) -> bool``: whether pair ``p`` is computed this step, from its
  squared centre distance ``dist2`` [m^2] and radius sum ``rsum`` [m] (``touching``: ``dist2 <
  rsum^2``; a cemented law also computes apart spheres held by a cement). A pair not engaged has
  its history columns 0:3 cleared.
* ``forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0, ut1, ut2, spin, mass, hist, dt, c)
  -> (acts, fn, ft0, ft1, ft2, energy)``: the normal force ``fn`` [N] (repulsive > 0, damping
  included), the tangential force on i ``ft`` [N] (history ``hist[p]`` updated, Coulomb cap) and
  the elastic energy [J] of an engaged pair, from the overlap ``delta`` [m], unit normal ``n``, the
  relative motion ``un`` [m/s], ``ut`` [m/s], ``spin`` [rad/s] of ``contact_frame``; ``acts`` False
  means nothing is applied. ``c`` is the law's tuple of float constants (``constants(params, dt)``).

The loop kinds, compiled once per ``(forces, engaged)`` and loop flags (``lru_cache``):

* ``pair_loop``: over a neighbour list, with image shifts, a deforming cell, the energy
  (``with_energy``) and the Love-Weber sums;
* ``all_pairs_loop``: every pair ``i < j`` of all rows, history ``[n, n, width]`` (test oracle);
* ``single_kernel``: one pair, for diagnostics.

``law_interface`` turns a law's pieces into its ``compute``, ``compute_all_pairs`` and ``single``.

On-disk cache: the loops are compiled with ``cache=True``. Numba keys a closure's cache by its
pickled cell contents, and a captured Numba function pickles with a per-process id, so a loop
closing over the law's function would compile again in every process. The loops therefore close
over their boolean flags only and see the pair kernel as the global ``pair`` of their own globals,
under a qualified name built from the law functions' names, compile-time constants and code
digests (``_name``): a law function may close over bools and numbers only. (As for every cached
kernel, an edit of a module the law functions call, e.g. ``contact_frame``, is not seen: clear
the ``__pycache__`` folders.)
"""
import hashlib
import marshal
import re
import sys
import types
from functools import lru_cache

import numpy as np
from numba import njit

from pardem.physics.contact_frame import (NO_RATE, NO_SHIFT, add_love_weber, affine_motion,
                                          any_rate, check_pairs, clear_history, contact_geometry,
                                          pair_separation, relative_motion, scatter_pair,
                                          shear_motion, write_pair)
from pardem.physics.exact_accumulate import NLIMB
from pardem.physics.exact_accumulate import add as exact_add
from pardem.physics.exact_accumulate import normalize as exact_normalize
from pardem.physics.pair_loads import add_in_order


@njit(cache=True, inline="always", error_model="numpy")
def touching(p, hist, dist2, rsum):
    """``engaged`` of a law without cohesion: the spheres overlap."""
    return dist2 < rsum * rsum


@lru_cache(maxsize=None)
def _pair(forces, engaged, deforming):
    """The inline kernel of one pair: geometry, relative motion (plus the affine part when
    ``deforming``), the law's ``forces``, the output ``out[9]`` = (F_i, T_i, T_j)."""
    @njit(cache=True, inline="always", error_model="numpy")
    def pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w, radius, mass, hist, dt, c, out):
        d0, d1, d2, dist2, ri, rj, rsum = pair_separation(i, j, s0, s1, s2, x, radius)
        if not engaged(p, hist, dist2, rsum):
            clear_history(hist, p)
            return False, 0.0
        n0, n1, n2, delta, li, lj = contact_geometry(d0, d1, d2, dist2, ri, rj, rsum)
        un, ut0, ut1, ut2, spin = relative_motion(i, j, v, w, n0, n1, n2, li, lj)
        if deforming:
            un, ut0, ut1, ut2 = affine_motion(un, ut0, ut1, ut2, d0, d1, d2, n0, n1, n2, g0, g1, g2)
        acts, fn, f0, f1, f2, energy = forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0,
                                              ut1, ut2, spin, mass, hist, dt, c)
        if acts:
            write_pair(out, n0, n1, n2, fn, f0, f1, f2, li, lj)
        return acts, energy
    return pair


BLOCK = 64   # pairs per block of the neighbour-list loop (64 to 128 measured best)


@njit(cache=True, inline="always", error_model="numpy")
def _relative_motion(dv0, dv1, dv2, wi0, wi1, wi2, wj0, wj1, wj2, n0, n1, n2, li, lj):
    """``contact_frame.relative_motion`` from gathered values (``dv = v_i - v_j``, ``w_i``, ``w_j``),
    the same arithmetic in the same order (the bitwise tests compare the two loops)."""
    a0 = li * wi0 + lj * wj0
    a1 = li * wi1 + lj * wj1
    a2 = li * wi2 + lj * wj2
    u0 = dv0 + a1 * n2 - a2 * n1
    u1 = dv1 + a2 * n0 - a0 * n2
    u2 = dv2 + a0 * n1 - a1 * n0
    un = u0 * n0 + u1 * n1 + u2 * n2
    spin = 0.5 * ((wi0 + wj0) * n0 + (wi1 + wj1) * n1 + (wi2 + wj2) * n2)
    return un, u0 - un * n0, u1 - un * n1, u2 - un * n2, spin


@lru_cache(maxsize=None)
def pair_loop(forces, engaged, periodic, deforming=False, with_energy=True, exact=False,
              with_stress=True, *, history_width, with_mass=True, sheared=False, ordered=False):
    """The compiled neighbour-list kernel of one law function and loop choice (built once).

    ``loop(i, j, shift, rate, x, v, w, radius, mass, f, t, history, dt, c, n_owned, acc, xacc,
    order, loads)``
    adds the pair forces and torques to ``f``, ``t`` [n_total, 3] (owned and ghost rows alike),
    updates ``history`` [n_pairs, width], adds the Love-Weber sums of the pairs whose ``i`` is
    owned to ``acc`` [10] (``contact_frame.add_love_weber``) and returns their elastic energy [J]
    (0 unless ``with_energy``: its arithmetic is then left out, 8 % of the loop). ``shift``
    [n_pairs, 3] [m] and the cell's diagonal strain rate ``rate`` [3] [1/s] are read only when
    ``periodic`` and ``deforming``; ``c`` is the law's constants tuple. ``sheared``: ``rate`` is
    the shearing cell's velocity gradient [6] (``PeriodicCell.gradient``: diagonal, then ``dv_x/dy,
    dv_x/dz, dv_y/dz``), its affine motion ``contact_frame.shear_motion``.

    ``history_width``: the columns of ``history``, compiled in as a constant (the history copies
    then unroll; with unsigned row indices, which need no negative-index wrap-around per access:
    10 % off the loop alone and 6 % off a GRAN step at n = 40).

    ``with_mass``: gather the masses of both ends for the law (``forces`` reads ``mass[i]``,
    ``mass[j]``); a law that never reads them (no damping) is compiled with False, and then sees
    ones (a fifth of the gather pass: 1.3 ns of 28 ns per pair, GRAN n = 40).

    ``with_stress``: add the nine Love-Weber sums to ``acc`` (else only the contact count: the
    steps nothing reads the stress on skip their arithmetic, LAMMPS' vflag; implied by ``exact``).

    ``exact`` (reproducible runs): the nine Love-Weber sums and the energy are instead added
    exactly, term by term, into ``xacc`` [10, NLIMB] int64 (``physics.exact_accumulate``, rows
    0-8 and 9, normalized at the end), so that their global sums do not depend on the number of
    ranks; ``acc`` then gets the contact count only, and the loop returns 0, or NaN when a term
    was not finite.

    Blocked: the pairs go by blocks of ``BLOCK``: a gather pass copies the inputs
    (branch vector, radii, ``v_i - v_j``, ``w_i``, ``w_j``, history row, masses) of the block's
    engaged pairs, packed in their order into the first slots of block arrays (every pair fills
    the next free slot, which only an engaged pair keeps: no branch; the values of row ``i`` read
    once per run of pairs with the same ``i``; the history columns 0:3 of every pair cleared, an
    engaged pair's row is written back after the law), a pass with no indirect access and no
    branch on contact runs the law over the packed slots (LLVM vectorises it: four pairs per AVX2
    instruction, so the long chain of square roots and divisions of one pair no longer bounds the
    loop; most listed pairs of a dense packing touch, but a third or so do not, and they cost no
    law arithmetic), and a scatter pass adds the loads in pair order to both rows in memory (row
    ``i`` is in the cache; keeping a run's i-side in registers needs a test per pair that
    mispredicts when runs are short; measured in ``benchmarks/results/gran_shear.md``).
    Every value is computed by the same operations as the one-pair kernel of ``all_pairs_loop``
    and ``single``, and the loads, sums and energy are added in the same order, so the results
    are the same bits (``tests/test_contacts.py`` compares them).
    ``ordered``: the pairs are computed in another order than the list's, and their loads added
    by ``pair_loads.add_in_order`` afterwards in the list's order (so the bits are those of the
    one-pass loop): ``i, j, shift`` are then the pairs in computing order, pair q's history row is
    ``history[order[q]]`` and its loads go to ``loads[q]`` (F_i, T_i, -F_i, T_j) instead of
    ``f``, ``t``; the Love-Weber sums must then be exact or left out (their register sums would
    follow the computing order). Rows in spatial order, computed by first row, read memory near
    each other, where the list's key order reads the second ends at random.
    The law's ``forces`` sees block indices: ``p`` indexes the history (a Fortran-ordered view
    ``[BLOCK, width]`` of the block's rows) and ``i``, ``j`` index ``mass`` only (the block's
    masses); a law must not use them for anything else.
    """
    pair = _pair(forces, engaged, bool(deforming))
    return _jit(_list_loop(bool(periodic), bool(deforming), bool(with_energy), bool(exact),
                           bool(with_stress) or bool(exact), int(history_width),
                           bool(with_mass), bool(sheared), bool(ordered)), pair,
                _name(forces, engaged), forces=forces, engaged=engaged)


NO_XACC = np.zeros((10, NLIMB), dtype=np.int64)   # the exact accumulator of loops without ``exact``
NO_ORDER = np.zeros(0, dtype=np.int64)             # ``order`` and ``loads`` of loops without ``ordered``
NO_LOADS = np.zeros((0, 12))


def _list_loop(periodic, deforming, with_energy, exact, with_stress, history_width, with_mass,
               sheared=False, ordered=False):
    B = BLOCK
    WIDTH = history_width

    def loop(pi, pj, shift, rate, x, v, w, radius, mass, f, t, hist, dt, c, n_owned, acc, xacc,
             order, loads):
        energy = 0.0
        s0 = s1 = s2 = 0.0
        g0 = g1 = g2 = 0.0
        # Love-Weber sums in registers (an array accumulator would be stored every pair, since
        # the compiler cannot prove it does not alias f and t)
        a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
        count = 0
        ok = True
        g3 = g4 = g5 = 0.0
        if deforming:
            g0, g1, g2 = rate[0], rate[1], rate[2]
        if sheared:
            g3, g4, g5 = rate[3], rate[4], rate[5]
        width = WIDTH                # a compile-time constant: the history copies unroll
        gat = np.empty((14, B))      # per slot: d (3), r_i, r_j, v_i - v_j (3), w_i (3), w_j (3)
        res = np.empty((11, B))      # per slot: F_i (3), T_i (3), T_j (3), energy, acts
        hb = np.empty((width, B))    # the slots' history rows, one column each
        hT = hb.T                    # [B, width], unit stride along the block
        mb = np.ones(2 * B)          # masses of the i ends, then of the j ends (with_mass)
        slot = np.empty(B, dtype=np.int64)   # the pair of each slot
        n_pairs = pi.shape[0]
        ci = np.uint64(x.shape[0])   # the row whose values are in xi, rad_i, vi, wi, mass_i
        xi0 = xi1 = xi2 = rad_i = vi0 = vi1 = vi2 = wi0 = wi1 = wi2 = mass_i = 0.0
        for p0 in range(0, n_pairs, B):
            m = min(B, n_pairs - p0)
            if ordered:              # a pair acting nothing adds -0.0 (x + (-0.0) == x)
                for p in range(p0, p0 + m):
                    for col in range(12):
                        loads[p, col] = -0.0
            nt = 0                   # slots filled: the engaged pairs of the block, in order
            for k in range(m):       # gather
                p = p0 + k
                hp = order[p] if ordered else p     # the pair's history row
                # unsigned rows: no negative-index wrap-around code per access
                i = np.uint64(pi[p])
                j = np.uint64(pj[p])
                if periodic:
                    s0 = shift[p, 0]
                    s1 = shift[p, 1]
                    s2 = shift[p, 2]
                if i != ci:          # a new run of pairs with this i: its row read once
                    ci = i
                    xi0 = x[i, 0]
                    xi1 = x[i, 1]
                    xi2 = x[i, 2]
                    rad_i = radius[i]
                    vi0 = v[i, 0]
                    vi1 = v[i, 1]
                    vi2 = v[i, 2]
                    wi0 = w[i, 0]
                    wi1 = w[i, 1]
                    wi2 = w[i, 2]
                    if with_mass:
                        mass_i = mass[i]
                # as contact_frame.pair_separation (exactly antisymmetric grouping)
                d0 = (x[j, 0] - xi0) + s0
                d1 = (x[j, 1] - xi1) + s1
                d2 = (x[j, 2] - xi2) + s2
                rad_j = radius[j]
                # every pair fills slot nt, which only an engaged pair keeps (no branch)
                gat[0, nt] = d0
                gat[1, nt] = d1
                gat[2, nt] = d2
                gat[3, nt] = rad_i
                gat[4, nt] = rad_j
                gat[5, nt] = vi0 - v[j, 0]
                gat[6, nt] = vi1 - v[j, 1]
                gat[7, nt] = vi2 - v[j, 2]
                gat[8, nt] = wi0
                gat[9, nt] = wi1
                gat[10, nt] = wi2
                gat[11, nt] = w[j, 0]
                gat[12, nt] = w[j, 1]
                gat[13, nt] = w[j, 2]
                for col in range(width):
                    hb[col, nt] = hist[hp, col]
                if with_mass:        # only laws that read masses (damping) pay for them
                    mb[nt] = mass_i
                    mb[B + nt] = mass[j]
                slot[nt] = p
                engage = engaged(nt, hT, d0 * d0 + d1 * d1 + d2 * d2, rad_i + rad_j)  # noqa: F821
                # as clear_history: an engaged pair's row is written back after the law
                hist[hp, 0] = 0.0
                hist[hp, 1] = 0.0
                hist[hp, 2] = 0.0
                nt += 1 if engage else 0
            for k in range(nt):      # the law over the engaged pairs, no indirect access, no
                d0 = gat[0, k]       # branch on contact: vectorised
                d1 = gat[1, k]
                d2 = gat[2, k]
                ri = gat[3, k]
                rj = gat[4, k]
                dist2 = d0 * d0 + d1 * d1 + d2 * d2
                rsum = ri + rj
                n0, n1, n2, delta, li, lj = contact_geometry(d0, d1, d2, dist2, ri, rj, rsum)
                un, ut0, ut1, ut2, spin = _relative_motion(
                    gat[5, k], gat[6, k], gat[7, k], gat[8, k], gat[9, k], gat[10, k],
                    gat[11, k], gat[12, k], gat[13, k], n0, n1, n2, li, lj)
                if sheared:
                    un, ut0, ut1, ut2 = shear_motion(un, ut0, ut1, ut2, d0, d1, d2, n0, n1,
                                                     n2, g0, g1, g2, g3, g4, g5)
                elif deforming:
                    un, ut0, ut1, ut2 = affine_motion(un, ut0, ut1, ut2, d0, d1, d2, n0, n1,
                                                      n2, g0, g1, g2)
                acts, fn, ft0, ft1, ft2, e = forces(k, k, B + k, ri, rj, rsum, delta, n0,  # noqa: F821
                                                    n1, n2, un, ut0, ut1, ut2, spin, mb, hT,
                                                    dt, c)
                # as contact_frame.write_pair
                c0 = n1 * ft2 - n2 * ft1
                c1 = n2 * ft0 - n0 * ft2
                c2 = n0 * ft1 - n1 * ft0
                res[0, k] = ft0 - fn * n0
                res[1, k] = ft1 - fn * n1
                res[2, k] = ft2 - fn * n2
                res[3, k] = li * c0
                res[4, k] = li * c1
                res[5, k] = li * c2
                res[6, k] = lj * c0
                res[7, k] = lj * c1
                res[8, k] = lj * c2
                res[9, k] = e
                res[10, k] = 1.0 if acts else 0.0
            for k in range(nt):      # the engaged pairs' history rows back
                p = slot[k]
                hp = order[p] if ordered else p
                for col in range(width):
                    hist[hp, col] = hb[col, k]
            for k in range(nt):      # scatter, in pair order
                if res[10, k] == 0.0:
                    continue
                p = slot[k]
                i = pi[p]
                o0 = res[0, k]
                o1 = res[1, k]
                o2 = res[2, k]
                if ordered:          # the loads are added later, in the list's order
                    for col in range(3):
                        loads[p, col] = res[col, k]          # +F_i on i
                        loads[p, 3 + col] = res[3 + col, k]  # T_i
                        loads[p, 6 + col] = -res[col, k]     # x - F == x + (-F), bitwise
                        loads[p, 9 + col] = res[6 + col, k]  # T_j
                else:                # as pair_loads.scatter_pair (row i in the cache: no run
                    iu = np.uint64(i)    # kept in registers, whose test mispredicts)
                    ju = np.uint64(pj[p])
                    f[iu, 0] += o0
                    f[iu, 1] += o1
                    f[iu, 2] += o2
                    f[ju, 0] -= o0
                    f[ju, 1] -= o1
                    f[ju, 2] -= o2
                    t[iu, 0] += res[3, k]
                    t[iu, 1] += res[4, k]
                    t[iu, 2] += res[5, k]
                    t[ju, 0] += res[6, k]
                    t[ju, 1] += res[7, k]
                    t[ju, 2] += res[8, k]
                if i < n_owned:   # counted once over the ranks (the owner of the lower gid)
                    b0 = gat[0, k]
                    b1 = gat[1, k]
                    b2 = gat[2, k]
                    count += 1
                    if exact:
                        ok &= exact_add(xacc, 0, b0 * o0)  # noqa: F821
                        ok &= exact_add(xacc, 1, b0 * o1)  # noqa: F821
                        ok &= exact_add(xacc, 2, b0 * o2)  # noqa: F821
                        ok &= exact_add(xacc, 3, b1 * o0)  # noqa: F821
                        ok &= exact_add(xacc, 4, b1 * o1)  # noqa: F821
                        ok &= exact_add(xacc, 5, b1 * o2)  # noqa: F821
                        ok &= exact_add(xacc, 6, b2 * o0)  # noqa: F821
                        ok &= exact_add(xacc, 7, b2 * o1)  # noqa: F821
                        ok &= exact_add(xacc, 8, b2 * o2)  # noqa: F821
                        if with_energy:
                            ok &= exact_add(xacc, 9, res[9, k])  # noqa: F821
                        continue
                    if with_energy:
                        energy += res[9, k]
                    if not with_stress:
                        continue
                    a00 += b0 * o0
                    a01 += b0 * o1
                    a02 += b0 * o2
                    a10 += b1 * o0
                    a11 += b1 * o1
                    a12 += b1 * o2
                    a20 += b2 * o0
                    a21 += b2 * o1
                    a22 += b2 * o2
        add_love_weber(acc, a00, a01, a02, a10, a11, a12, a20, a21, a22, count)
        if exact:
            exact_normalize(xacc)  # noqa: F821
            return energy if ok else np.nan
        return energy
    return loop


@lru_cache(maxsize=None)
def _module_digest(module):
    """A digest of the code and plain constants of ``module`` (its functions' byte code, compiled
    or not, and its numbers and strings): an edit of any kernel the law calls changes it. Read
    from the loaded module, not its file (the physics layer opens no file)."""
    h = hashlib.sha1()
    for key, value in sorted(vars(sys.modules[module]).items()):
        code = getattr(getattr(value, "py_func", value), "__code__", None)
        if code is not None:
            h.update(key.encode() + marshal.dumps(code))
        elif isinstance(value, (int, float, str, tuple)) and not key.startswith("__"):
            h.update(f"{key}={value!r}".encode())
    return h.hexdigest()[:10]


def _name(*functions):
    """A file-name-safe name of Numba functions, of the constants they close over and of their
    modules' code (an edited law compiles afresh instead of loading the loop of the old one)."""
    parts = []
    for fn in functions:
        py = fn.py_func
        cells = "_".join(repr(c.cell_contents) for c in py.__closure__ or ())
        parts.append(f"{py.__module__}.{py.__qualname__.replace('.<locals>', '')}_{cells}_"
                     f"{_module_digest(py.__module__)}")
    return re.sub(r"[^A-Za-z0-9_.]", "_", "__".join(parts))


def _jit(loop, pair, name, **kernels):
    """``loop`` (a plain function reading the global ``pair``, and the globals ``kernels``, e.g.
    the law's ``forces`` and ``engaged``) compiled with them in its globals, cached on disk under
    a qualified name of its own (module docstring)."""
    globs = dict(loop.__globals__)
    globs["pair"] = pair
    globs.update(kernels)
    fn = types.FunctionType(loop.__code__, globs, loop.__name__, loop.__defaults__,
                            loop.__closure__)
    fn.__qualname__ = f"{loop.__qualname__}.{name}"
    fn.__module__ = loop.__module__
    return njit(cache=True, error_model="numpy")(fn)


@lru_cache(maxsize=None)
def all_pairs_loop(forces, engaged):
    """``loop(x, v, w, radius, mass, f, t, history_full, dt, c)``: brute-force O(n^2) twin of
    ``pair_loop`` over every row pair ``i < j`` (no shifts), history ``[n, n, width]`` indexed
    ``[i, j]``; returns the elastic energy [J] (test oracle)."""
    return _jit(_all_pairs_loop(), _pair(forces, engaged, False), _name(forces, engaged))


def _all_pairs_loop():
    def loop(x, v, w, radius, mass, f, t, hist_full, dt, c):
        out = np.empty(9)
        energy = 0.0
        n = x.shape[0]
        for i in range(n):
            hist_i = hist_full[i]
            for j in range(i + 1, n):
                acts, e = pair(j, i, j, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, x, v, w, radius, mass,  # noqa: F821
                               hist_i, dt, c, out)
                if acts:
                    scatter_pair(i, j, f, t, out)
                    energy += e
        return energy
    return loop


@lru_cache(maxsize=None)
def single_kernel(forces, engaged):
    """``one(i, j, s, x, v, w, radius, mass, hist, dt, c, out)``: pair ``(i, j)`` with image shift
    ``s`` [3] [m] and history ``hist`` [1, width]; returns ``(acts, energy [J])``, fills
    ``out[9]``."""
    return _jit(_single(), _pair(forces, engaged, False), _name(forces, engaged))


def _single():
    def one(i, j, s, x, v, w, radius, mass, hist, dt, c, out):
        return pair(0, i, j, s[0], s[1], s[2], 0.0, 0.0, 0.0, x, v, w, radius, mass, hist, dt, c,  # noqa: F821
                    out)
    return one


def law_interface(pair_function, constants, history_width, reads_mass=None):
    """``(compute, compute_all_pairs, single)`` of a law from its pieces: ``pair_function(params)
    -> (forces, engaged)``, ``constants(params, dt) -> tuple of floats``,
    ``history_width(params) -> int`` and ``reads_mass(params) -> bool`` (whether ``forces`` reads
    the masses; None: always) (see the module docstring)."""

    def compute(params, elements, i, j, history, dt, shift=None, rate=None, acc=None,
                with_energy=True, xacc=None, with_stress=True, order=None):
        """Add the contact forces of the pairs ``(i[p], j[p])`` to ``elements.f``/``elements.t``.

        i, j : [n_pairs] rows (ordered by gid within each pair); history : [n_pairs, width]
        (``history_width(params)``; columns 0:3 the tangential force on i [N]), updated in place
        (columns 0:3 zeroed for pairs not engaged); dt [s] : step; shift : optional [n_pairs, 3]
        periodic image shift added to ``x_j`` [m]; rate : optional diagonal strain rate [3] [1/s]
        of the periodic cell, or its velocity gradient [6] [1/s] when it shears (``PeriodicCell.
        gradient``) (needs ``shift``); acc : optional [10] Love-Weber sums, added to.
        Returns the elastic energy [J] of the pairs whose ``i`` is owned (NaN when not
        ``with_energy``: the loop then does not compute it). xacc : optional [10, NLIMB] int64
        exact accumulator (reproducible runs, ``pair_loop``'s ``exact``): the Love-Weber sums and
        the energy go there, exactly (added to), ``acc`` gets the contact count only, and the
        return value is 0 (NaN on a non-finite term). with_stress False: ``acc`` gets the
        contact count only (the Love-Weber sums are left out; ignored with ``xacc``).
        order : optional ``(order, i_c, j_c, shift_c, loads, inc_start, inc)``: compute the
        pairs in the order ``order`` (``i_c, j_c, shift_c`` the pairs and shifts in that order,
        ``loads`` [n_pairs, 12] scratch) and add their loads in list order
        (``pair_lists.compute_order``): the same bits; needs ``xacc``, or neither the energy
        nor the stress (their float sums would follow the computing order).
        """
        e = elements
        check_pairs(i, j, history, shift, history_width(params))
        if order is not None and xacc is None and (with_energy or with_stress):
            raise ValueError("compute(order=...) needs the exact sums (xacc), or neither the energy "
                             "nor the stress")
        forces, engaged = pair_function(params)
        sheared = rate is not None and len(rate) == 6
        loop = pair_loop(forces, engaged, shift is not None,
                         rate is not None and (sheared or any_rate(rate)), bool(with_energy),
                         xacc is not None, bool(with_stress), history_width=history.shape[1],
                         with_mass=True if reads_mass is None else bool(reads_mass(params)),
                         sheared=sheared, ordered=order is not None)
        if order is not None:
            q, i, j, shift, loads, inc_start, inc = order
        else:
            q, loads = NO_ORDER, NO_LOADS
        energy = loop(i, j, NO_SHIFT if shift is None else shift, NO_RATE if rate is None else rate,
                      e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, history, float(dt),
                      constants(params, dt), e.n_owned, np.zeros(10) if acc is None else acc,
                      NO_XACC if xacc is None else xacc, q, loads)
        if order is not None:
            add_in_order(loads, inc_start, inc, e.f, e.t)
        if xacc is not None:
            return energy
        return energy if with_energy else float("nan")

    def compute_all_pairs(params, elements, history_full, dt):
        """Brute-force version of ``compute`` over all row pairs, history ``[n, n, width]``
        (tests)."""
        e = elements
        forces, engaged = pair_function(params)
        return all_pairs_loop(forces, engaged)(e.x, e.v, e.w, e.radius, e.mass, e.f, e.t,
                                               history_full, float(dt), constants(params, dt))

    def single(params, elements, i, j, history_row, dt, shift=(0.0, 0.0, 0.0)):
        """Diagnostics of one pair, nothing modified: dict with ``force_i``, ``torque_i``,
        ``torque_j`` [N, N m], ``history`` (the value the step would store), ``energy`` [J] and
        ``touching`` (the pair acts)."""
        e = elements
        hist = np.array(history_row, dtype=np.float64).reshape(1, history_width(params))
        out = np.zeros(9)
        s = np.asarray(shift, dtype=np.float64)
        forces, engaged = pair_function(params)
        acts, energy = single_kernel(forces, engaged)(i, j, s, e.x, e.v, e.w, e.radius, e.mass,
                                                      hist, float(dt), constants(params, dt), out)
        return {"touching": bool(acts), "force_i": out[0:3].copy(), "torque_i": out[3:6].copy(),
                "torque_j": out[6:9].copy(), "history": hist[0].copy(), "energy": float(energy)}

    return compute, compute_all_pairs, single
