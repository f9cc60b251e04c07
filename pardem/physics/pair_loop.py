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
under a qualified name built from the law functions' names, compile-time constants and source
digests (``_name``): a law function may close over bools and numbers only. (As for every cached
kernel, an edit of a module the law functions call, e.g. ``contact_frame``, is not seen: clear
the ``__pycache__`` folders.)
"""
import hashlib
import re
import types
from functools import lru_cache

import numpy as np
from numba import njit

from pardem.physics.contact_frame import (NO_RATE, NO_SHIFT, add_love_weber, affine_motion,
                                          check_pairs, clear_history, contact_geometry,
                                          pair_separation, relative_motion, scatter_pair,
                                          write_pair)
from pardem.physics.exact_accumulate import NLIMB
from pardem.physics.exact_accumulate import add as exact_add
from pardem.physics.exact_accumulate import normalize as exact_normalize


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


@lru_cache(maxsize=None)
def pair_loop(forces, engaged, periodic, deforming=False, with_energy=True, exact=False):
    """The compiled neighbour-list kernel of one law function and loop choice (built once).

    ``loop(i, j, shift, rate, x, v, w, radius, mass, f, t, history, dt, c, n_owned, acc, xacc)``
    adds the pair forces and torques to ``f``, ``t`` [n_total, 3] (owned and ghost rows alike),
    updates ``history`` [n_pairs, width], adds the Love-Weber sums of the pairs whose ``i`` is
    owned to ``acc`` [10] (``contact_frame.add_love_weber``) and returns their elastic energy [J]
    (0 unless ``with_energy``: its arithmetic is then left out, 8 % of the loop). ``shift``
    [n_pairs, 3] [m] and the cell's diagonal strain rate ``rate`` [3] [1/s] are read only when
    ``periodic`` and ``deforming``; ``c`` is the law's constants tuple.

    ``exact`` (reproducible runs): the nine Love-Weber sums and the energy are instead added
    exactly, term by term, into ``xacc`` [10, NLIMB] int64 (``physics.exact_accumulate``, rows
    0-8 and 9, normalized at the end), so that their global sums do not depend on the number of
    ranks; ``acc`` then gets the contact count only, and the loop returns 0, or NaN when a term
    was not finite.
    """
    pair = _pair(forces, engaged, bool(deforming))
    return _jit(_list_loop(bool(periodic), bool(deforming), bool(with_energy), bool(exact)), pair,
                _name(forces, engaged))


NO_XACC = np.zeros((10, NLIMB), dtype=np.int64)   # the exact accumulator of loops without ``exact``


def _list_loop(periodic, deforming, with_energy, exact):
    def loop(pi, pj, shift, rate, x, v, w, radius, mass, f, t, hist, dt, c, n_owned, acc, xacc):
        out = np.empty(9)
        energy = 0.0
        s0 = s1 = s2 = 0.0
        g0 = g1 = g2 = 0.0
        # Love-Weber sums in registers (an array accumulator would be stored every pair, since
        # the compiler cannot prove it does not alias f and t)
        a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
        count = 0
        ok = True
        if deforming:
            g0, g1, g2 = rate[0], rate[1], rate[2]
        for p in range(pi.shape[0]):
            i = pi[p]
            j = pj[p]
            if periodic:
                s0 = shift[p, 0]
                s1 = shift[p, 1]
                s2 = shift[p, 2]
            acts, e = pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w, radius, mass, hist, dt, c, out)  # noqa: F821
            if acts:
                scatter_pair(i, j, f, t, out)
                if i < n_owned:   # counted once over the ranks (the owner of the lower gid)
                    b0 = (x[j, 0] - x[i, 0]) + s0
                    b1 = (x[j, 1] - x[i, 1]) + s1
                    b2 = (x[j, 2] - x[i, 2]) + s2
                    count += 1
                    if exact:
                        ok &= exact_add(xacc, 0, b0 * out[0])  # noqa: F821
                        ok &= exact_add(xacc, 1, b0 * out[1])  # noqa: F821
                        ok &= exact_add(xacc, 2, b0 * out[2])  # noqa: F821
                        ok &= exact_add(xacc, 3, b1 * out[0])  # noqa: F821
                        ok &= exact_add(xacc, 4, b1 * out[1])  # noqa: F821
                        ok &= exact_add(xacc, 5, b1 * out[2])  # noqa: F821
                        ok &= exact_add(xacc, 6, b2 * out[0])  # noqa: F821
                        ok &= exact_add(xacc, 7, b2 * out[1])  # noqa: F821
                        ok &= exact_add(xacc, 8, b2 * out[2])  # noqa: F821
                        if with_energy:
                            ok &= exact_add(xacc, 9, e)  # noqa: F821
                        continue
                    if with_energy:
                        energy += e
                    a00 += b0 * out[0]
                    a01 += b0 * out[1]
                    a02 += b0 * out[2]
                    a10 += b1 * out[0]
                    a11 += b1 * out[1]
                    a12 += b1 * out[2]
                    a20 += b2 * out[0]
                    a21 += b2 * out[1]
                    a22 += b2 * out[2]
        add_love_weber(acc, a00, a01, a02, a10, a11, a12, a20, a21, a22, count)
        if exact:
            exact_normalize(xacc)  # noqa: F821
            return energy if ok else np.nan
        return energy
    return loop


@lru_cache(maxsize=None)
def _source_digest(path):
    with open(path, "rb") as fh:
        return hashlib.sha1(fh.read()).hexdigest()[:10]


def _name(*functions):
    """A file-name-safe name of Numba functions, of the constants they close over and of their
    source files (an edited law compiles afresh instead of loading the loop of the old one)."""
    parts = []
    for fn in functions:
        py = fn.py_func
        cells = "_".join(repr(c.cell_contents) for c in py.__closure__ or ())
        parts.append(f"{py.__module__}.{py.__qualname__.replace('.<locals>', '')}_{cells}_"
                     f"{_source_digest(py.__code__.co_filename)}")
    return re.sub(r"[^A-Za-z0-9_.]", "_", "__".join(parts))


def _jit(loop, pair, name):
    """``loop`` (a plain function reading the global ``pair``) compiled with ``pair`` in its
    globals, cached on disk under a qualified name of its own (module docstring)."""
    globs = dict(loop.__globals__)
    globs["pair"] = pair
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


def law_interface(pair_function, constants, history_width):
    """``(compute, compute_all_pairs, single)`` of a law from its pieces: ``pair_function(params)
    -> (forces, engaged)``, ``constants(params, dt) -> tuple of floats`` and
    ``history_width(params) -> int`` (see the module docstring)."""

    def compute(params, elements, i, j, history, dt, shift=None, rate=None, acc=None,
                with_energy=True, xacc=None):
        """Add the contact forces of the pairs ``(i[p], j[p])`` to ``elements.f``/``elements.t``.

        i, j : [n_pairs] rows (ordered by gid within each pair); history : [n_pairs, width]
        (``history_width(params)``; columns 0:3 the tangential force on i [N]), updated in place
        (columns 0:3 zeroed for pairs not engaged); dt [s] : step; shift : optional [n_pairs, 3]
        periodic image shift added to ``x_j`` [m]; rate : optional diagonal strain rate [3] [1/s]
        of the periodic cell (needs ``shift``); acc : optional [10] Love-Weber sums, added to.
        Returns the elastic energy [J] of the pairs whose ``i`` is owned (NaN when not
        ``with_energy``: the loop then does not compute it). xacc : optional [10, NLIMB] int64
        exact accumulator (reproducible runs, ``pair_loop``'s ``exact``): the Love-Weber sums and
        the energy go there, exactly (added to), ``acc`` gets the contact count only, and the
        return value is 0 (NaN on a non-finite term).
        """
        e = elements
        check_pairs(i, j, history, shift, history_width(params))
        forces, engaged = pair_function(params)
        loop = pair_loop(forces, engaged, shift is not None,
                         rate is not None and bool(np.any(rate != 0.0)), bool(with_energy),
                         xacc is not None)
        energy = loop(i, j, NO_SHIFT if shift is None else shift, NO_RATE if rate is None else rate,
                      e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, history, float(dt),
                      constants(params, dt), e.n_owned, np.zeros(10) if acc is None else acc,
                      NO_XACC if xacc is None else xacc)
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
