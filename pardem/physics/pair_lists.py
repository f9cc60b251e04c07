"""Kernels of a contact list rebuild after the cell-list scan (``neighbours``): the pairs put in
key order, the history carried over from the previous list, the image shifts in metres.

A pair's key is ``gid_i * 2^31 + gid_j`` (``gid_i < gid_j``), unique per pair. Reproducible runs
keep their lists in key order (``pardem.engine.contacts``), so the previous list, whose history the
new one inherits, is in key order too: the history is carried over by one merge of two sorted key
sequences, O(n_new + n_old), instead of a sort and a binary search per pair.

Pure functions over arrays: no MPI, no files.
"""
import numpy as np
from numba import njit

KEY_BASE = np.int64(1) << np.int64(31)


@njit(cache=True, error_model="numpy")
def _by_key(pairs, shifts, gid, grank, i_out, j_out, s_out, k_out):
    """Counting sort of ``pairs`` by the gid rank of their first end, then insertion sort of each
    run by the second end's gid (runs hold a few pairs): the order of increasing key."""
    n_rows = grank.shape[0]
    n = pairs.shape[0]
    start = np.zeros(n_rows + 1, dtype=np.int64)
    for p in range(n):
        start[grank[pairs[p, 0]] + 1] += 1
    for r in range(n_rows):
        start[r + 1] += start[r]
    cursor = start[:n_rows].copy()
    for p in range(n):
        a = grank[pairs[p, 0]]
        q = cursor[a]
        cursor[a] += 1
        i = pairs[p, 0]
        j = pairs[p, 1]
        gj = gid[j]
        # insertion into the run [start[a], q): ordered by the second end's gid
        while q > start[a] and gid[j_out[q - 1]] > gj:
            i_out[q] = i_out[q - 1]
            j_out[q] = j_out[q - 1]
            s_out[q, 0] = s_out[q - 1, 0]
            s_out[q, 1] = s_out[q - 1, 1]
            s_out[q, 2] = s_out[q - 1, 2]
            q -= 1
        i_out[q] = i
        j_out[q] = j
        s_out[q, 0] = shifts[p, 0]
        s_out[q, 1] = shifts[p, 1]
        s_out[q, 2] = shifts[p, 2]
    for p in range(n):
        k_out[p] = gid[i_out[p]] * KEY_BASE + gid[j_out[p]]


def order_by_key(pairs, shifts, gid, n_rows):
    """The pairs [n, 2] (rows, ``gid[i] < gid[j]``) and their shifts [n, 3] int8 in increasing key
    order: ``(i, j)`` int32 [n], ``shifts`` int8 [n, 3] and ``keys`` int64 [n] (fresh arrays). The
    same order as a sort of the keys (they are unique), in O(n + n_rows log n_rows): one
    counting sort by the first end over the ``n_rows`` rows ranked by gid."""
    n = pairs.shape[0]
    g = np.ascontiguousarray(gid[:n_rows], dtype=np.int64)
    grank = np.empty(n_rows, dtype=np.int64)
    grank[np.argsort(g, kind="stable")] = np.arange(n_rows, dtype=np.int64)
    i = np.empty(n, dtype=np.int32)
    j = np.empty(n, dtype=np.int32)
    s = np.empty((n, 3), dtype=np.int8)
    k = np.empty(n, dtype=np.int64)
    _by_key(np.ascontiguousarray(pairs), np.ascontiguousarray(shifts), g, grank, i, j, s, k)
    return i, j, s, k


@njit(cache=True, error_model="numpy")
def _merge(keys, table_keys, table_values, out):
    t = 0
    nt = table_keys.shape[0]
    width = out.shape[1]
    for p in range(keys.shape[0]):
        k = keys[p]
        while t < nt and table_keys[t] < k:
            t += 1
        # the first row of this key that is not all zeros (Contacts.table leaves those out)
        live = False
        u = t
        while u < nt and table_keys[u] == k and not live:
            for c in range(table_values.shape[1]):
                live |= table_values[u, c] != 0.0
            u += 1
        if live:
            for c in range(width):
                out[p, c] = table_values[u - 1, c]
        else:
            for c in range(width):
                out[p, c] = 0.0


@njit(cache=True, error_model="numpy")
def _ascending(a):
    for p in range(1, a.shape[0]):
        if a[p] < a[p - 1]:
            return False
    return True


def carry_history(keys, table_keys, table_values, width):
    """Rows of ``table_values`` [m, >= width] for ``keys`` [n] (increasing), zeros for keys not in
    the table or whose row is all zeros (so a row of signed zeros comes back as +0.0, as a table
    of the non-zero rows only, ``Contacts.table``, gives it): [n, width]. A table not in increasing key order (one joined from several ranks'
    parts) is sorted first (stable: of equal keys, the first in table order is taken, as
    ``contacts.lookup`` does)."""
    out = np.empty((len(keys), width))
    table_keys = np.ascontiguousarray(table_keys, dtype=np.int64)
    table_values = np.ascontiguousarray(table_values, dtype=np.float64)
    if len(table_keys) == 0:
        out[:] = 0.0
        return out
    if not _ascending(table_keys):
        order = np.argsort(table_keys, kind="stable")
        table_keys, table_values = table_keys[order], table_values[order]
    _merge(np.ascontiguousarray(keys, dtype=np.int64), table_keys, table_values, out)
    return out


@njit(cache=True, error_model="numpy")
def shift_metres_into(shifts, period, out):
    """``out[p] = shifts[p] * period`` [m] (``shifts`` int8 [n, 3], ``period`` [3], 0 along
    non-periodic axes): the image shifts of a list for the current cell edges, written in place
    (the same products as NumPy's ``shifts * period``)."""
    p0, p1, p2 = period[0], period[1], period[2]
    for p in range(shifts.shape[0]):
        out[p, 0] = np.float64(shifts[p, 0]) * p0
        out[p, 1] = np.float64(shifts[p, 1]) * p1
        out[p, 2] = np.float64(shifts[p, 2]) * p2
