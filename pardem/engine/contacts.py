"""Sphere-sphere contacts of one rank: the Verlet list, the per-pair history and the force call.

One contact law per run: a row of ``pardem.physics.contact_laws`` (``hertz_mindlin`` or
``linear_contact``, interface ``contact_laws.ContactLaw``: ``Params``, ``compute``,
``history_width``, ``persistent_rows``, ``normal_stiffness``). Pairs come from
``pardem.physics.neighbours.VerletList`` with at least one owned end, ordered by global id; a
pair joined by an intact bond is left out (the bond carries the interaction).

History (the tangential elastic force, [n_pairs, 3] N; wider when the law says so through its
``history_width(params)``, e.g. 9 columns for cemented Hertz-Mindlin contacts) belongs to a pair,
not to rows: it is keyed
by the gid pair ``key = gid_i * 2^31 + gid_j``. At every list rebuild the table of the previous
list (plus what migration brought) is looked up by key, so the history survives rebuilds, element
migration between ranks and checkpoints. Only pairs in contact carry a non-zero history, and only
those travel (an intact cement keeps its row non-zero, so it travels too).

Cemented pairs apart: a pair is listed while its centre distance is below ``R_i + R_j + skin`` at
a rebuild, and computed until the next rebuild whatever its distance. An intact cement is kept
listed as long as its gap stays below the skin; ``pardem.engine.cement`` refuses parameters for which a
cement could survive a gap of ``skin`` (its normal stretch at rupture ``sqrt(2 E_th / Sn)`` must be
below the skin), so no intact cement is ever dropped by a rebuild. A fading (broken) cement whose
spheres separate beyond the reach is dropped with its remaining fraction of force.

A pair with one ghost end is computed by both ranks from bitwise-identical inputs, so both hold
the same history; the energy and the Love-Weber sums count a pair on the rank owning its lower-gid
end only.

Spatial order (``sort_rows``, reproducible lists only): at the time loop's list rebuilds the
owned rows are stored in Morton order of cells of edge ``reach`` (``physics.pair_lists.
spatial_order``; on one process ``sort``, called by ``Simulation.rebuild_contacts``; on several,
``SlabComm.exchange``), and the pairs are computed by first row, so that a block of pairs reads rows
near each other in memory; their loads are then added row by row in key order
(``pair_loop``'s ``ordered``, ``pair_loads.add_in_order``), so every element receives the same
additions in the same order as from the list order: the bits do not change, whatever the rows'
storage order. The list itself (``i, j, keys``, and ``history`` when read) stays in key order.
Ranks with fewer than ``SORT_MIN_ROWS`` owned rows do not sort (``sorting``), nor ranks whose
rows are stored in a local order already (``scattered``, judged at list builds). ``Simulation``
turns it off with plates or walls (their forces are summed in row order).

Reproducible runs (``reproducible``: the same bits on any number of ranks): the
list is ordered by pair key (lower gid, then higher gid) at every build, so that each element
adds its contact forces in an order fixed by the gids alone (pairs ``(a, k)`` by ``a``, then
``(k, b)`` by ``b``), whatever the rank's rows and cell grid; every pair is computed with its
lower-gid end as ``i``, so ``f_ij = -f_ji`` bitwise on both ranks of a boundary pair. The
Love-Weber sums and the energy are accumulated exactly (``physics.exact_accumulate``) and
reduced by ``global_sums`` (``parallel.exact_sum``), independent of the decomposition.
"""
import inspect

import numpy as np

from pardem.parallel import exact_sum
from pardem.physics import exact_accumulate as xa
from pardem.physics.contact_frame import NO_SHIFT
from pardem.physics.neighbours import VerletList, max_displacement2
from pardem.physics.pair_lists import (carry_history, compute_order, order_by_key, scattered,
                                       shift_metres_into, spatial_order)
from pardem.physics.timestep import contact_stiffness
from pardem.physics.pair_lists import crossing_rows, shift_metres_rows  # noqa: I100

KEY_BASE = np.int64(1) << np.int64(31)

# the fields of ``Contacts.sums`` [10] (``physics.contact_frame.add_love_weber``): the Love-Weber sums
# ``sum d_a F_i,b`` [N m] in row-major order (the stress is ``sums[STRESS].reshape(3, 3) / V``,
# tension positive) and the number of pairs in contact, each this rank's share
STRESS = slice(0, 9)
N_TOUCHING = 9

# default of ``Contacts(reproducible=None)``: lists in key order and exact sums (module docstring)
REPRODUCIBLE = True

# default of ``Contacts.sort_rows`` for reproducible lists (module docstring, "Spatial order"), and
# the fewest owned rows a rank sorts: below, the rows stay in the caches whatever their order and
# the second pass costs more than locality gains (measured on GRAN-SHEAR at 8,000 and 64,000
# grains: docs/performance.md)
SORT_ROWS = True
SORT_MIN_ROWS = 30000
# a rank that does not sort judges again whether its rows are scattered every this many list builds
# (a flow mixes a lattice built in order)
SORT_JUDGE_EVERY = 16


def pair_keys(gid_i, gid_j):
    """int64 key of each gid pair (``gid_i < gid_j < 2^31``)."""
    return np.asarray(gid_i, dtype=np.int64) * KEY_BASE + np.asarray(gid_j, dtype=np.int64)


def lookup(keys, table_keys, table_values, width):
    """Rows of ``table_values`` for ``keys`` (zeros for keys not in the table)."""
    out = np.zeros((len(keys), width))
    if len(table_keys) == 0 or len(keys) == 0:
        return out
    order = np.argsort(table_keys, kind="stable")
    sk = table_keys[order]
    pos = np.minimum(np.searchsorted(sk, keys), len(sk) - 1)
    hit = sk[pos] == keys
    out[hit] = table_values[order[pos[hit]]]
    return out


def check_period(cell, reach):
    """ValueError unless every periodic edge of ``cell`` is at least twice the contact reach
    ``reach`` = 2 R_max + skin [m] (a grain would touch its own image twice). Checked with the
    global reach, the same on every rank (the list's own check uses this rank's largest radius:
    ranks could disagree and leave the others waiting)."""
    width = cell.widths   # the edges, or the face distances of a tilted cell
    short = cell.periodic & (width < 2.0 * reach)
    if np.any(short):
        a = int(np.argmax(short))
        raise ValueError(f"periodic axis {'xyz'[a]}: period {width[a]:.6g} m is "
                         f"shorter than twice the contact reach 2 R_max + skin = {reach:.6g} m")


class Contacts:
    """Contacts of one rank's elements under ``law`` (a ``contact_laws`` row) with ``params``.

    skin [m]: Verlet skin; cell: the ``PeriodicCell`` or None; reach [m]: the largest centre
    distance of a listed pair, ``2 R_max + skin`` over all ranks (it scales the rebuild margin of
    a deforming cell, so it must be the same on every rank). After ``rebuild``: ``i, j`` int32
    rows, ``shifts`` int8 [n, 3] image of j, ``keys`` int64, ``history`` [n, width] (``width``
    from ``law.history_width(params)``).
    After ``compute``: ``energy`` [J] and ``sums`` [10] (Love-Weber sums and contact count, this
    rank's share; see ``contact_frame.add_love_weber``). ``lost``: history rows the law marks
    persistent (``law.persistent_rows``, e.g. intact cements) that a rebuild could not find again
    in reach (0 when the parameters are checked, see the module docstring).
    """

    def __init__(self, law, params, skin, cell=None, reach=0.0, reproducible=None):
        self.reproducible = REPRODUCIBLE if reproducible is None else bool(reproducible)
        self.xacc = xa.zeros(10)    # exact Love-Weber sums (0-8) and energy (9) of this rank
        self.exact_ready = False    # xacc holds the sums of the last force evaluation
        self.stress_ready = True    # sums[STRESS] holds the Love-Weber sums of the last evaluation
        self.exact_ok = True        # ... and all its terms were finite
        self.law = law
        self.params = params
        self.width = int(law.history_width(params))
        self.skin = float(skin)
        self.cell = cell
        periodic = (False,) * 3 if cell is None else tuple(bool(p) for p in cell.periodic)
        self.periodic = any(periodic)
        self.vl = VerletList(self.skin, periodic=periodic)
        self.i = np.zeros(0, np.int32)
        self.j = np.zeros(0, np.int32)
        self.shifts = np.zeros((0, 3), np.int8)
        self.shift = None
        self._crossing = None        # the pairs whose shift is not zero (rewritten each step)
        self.keys = np.zeros(0, np.int64)
        self._hist_c = None          # the history in computing order, when it is the current one
        self.history = np.zeros((0, self.width))
        self.energy = 0.0
        self.sums = np.zeros(10)
        self.builds = 0
        self.lost = 0      # rows the law marks persistent (intact cements) dropped by rebuilds
        self.cut = float(reach)
        # the compute order of a spatially sorted list (built at the first step after a rebuild)
        self._order = None
        self.sort_rows = bool(SORT_ROWS and self.reproducible
                              and "order" in inspect.signature(law.compute).parameters)
        # whether this rank's rows are stored scattered (``pair_lists.scattered``; None: not judged
        # yet): only then does sorting pay (rows already in a local order, as a lattice built axis
        # by axis, run slower sorted: GRAN, docs/performance.md)
        self.scattered = None
        if cell is not None and cell.deforming and not self.cut > 0.0:
            raise ValueError("Contacts in a deforming cell need reach = 2 R_max + skin (> 0): it "
                             "scales the rebuild margin")

    @property
    def history(self):
        """The per-pair history [n_pairs, width] in list order (the class docstring). With
        ``sort_rows`` the force loop keeps it in its computing order between rebuilds; reading
        this attribute puts it back in list order (the same array object, which the next force
        evaluation reads again, so writes into it count)."""
        if self._hist_c is not None:
            self._history[self._order[0]] = self._hist_c
            self._hist_c = None
        return self._history

    @history.setter
    def history(self, value):
        self._hist_c = None
        self._history = value

    def set_params(self, params):
        """Change the law's parameters between steps (e.g. friction after a frictionless
        preparation, or the cement springs before cementation). The history is widened with zero
        columns, or narrowed when the dropped columns are all zero (else ValueError)."""
        width = int(self.law.history_width(params))
        h = self.history
        if width > h.shape[1]:
            h = np.concatenate([h, np.zeros((len(h), width - h.shape[1]))], axis=1)
        elif width < h.shape[1]:
            if np.any(h[:, width:] != 0.0):
                raise ValueError("contacts.set_params: the new law would drop a non-zero history "
                                 "(e.g. intact cement)")
            h = h[:, :width]
        self.params = params
        self.width = width
        self.history = np.ascontiguousarray(h)

    # -- list -----------------------------------------------------------------------------

    def table(self):
        """The pairs with a non-zero history: ``{"gid_i", "gid_j", "history"}`` (for migration)."""
        live = np.any(self.history != 0.0, axis=1)
        return {"gid_i": self.keys[live] // KEY_BASE, "gid_j": self.keys[live] % KEY_BASE,
                "history": self.history[live]}

    def rebuild(self, elements, bonds=None, table=None):
        """New list from the current rows; history looked up in ``table`` (default: the old list)."""
        e = elements
        if e.gid.size and int(e.gid.max()) >= int(KEY_BASE):
            raise ValueError("element gids must be below 2^31 for the contact keys")
        kw = {}
        if self.cell is not None:
            check_period(self.cell, self.cut)
            kw = {"box_lo": self.cell.lo, "box_hi": self.cell.hi,
                  "tilt": self.cell.tilt if self.cell.tilted else None}
        self.vl.rebuild(e.x, e.radius, e.gid, e.n_owned, e.n_total, **kw)
        pairs, shifts = self.vl.pairs, self.vl.shifts
        if self.reproducible:
            # key order (the keys are unique: the order of a sort of the keys), in O(n)
            i, j, shifts, keys = order_by_key(pairs, shifts, e.gid, e.n_total)
        else:
            i, j = pairs[:, 0], pairs[:, 1]
            keys = pair_keys(e.gid[i], e.gid[j])
        if bonds is not None and bonds.n:
            acting = bonds.intact    # a broken bond's pair interacts by contact
            keep = ~np.isin(keys, pair_keys(bonds.gid_i[acting], bonds.gid_j[acting]))
            i, j, shifts, keys = i[keep], j[keep], shifts[keep], keys[keep]
        if table is None and self.reproducible:   # the previous list, in key order
            table_keys, table_history = self.keys, self.history
        else:
            table = self.table() if table is None else table
            table_keys, table_history = pair_keys(table["gid_i"], table["gid_j"]), table["history"]
        if len(table_keys):
            must = self.law.persistent_rows(table_history)
            if np.any(must):   # e.g. an intact cement whose spheres moved beyond the reach
                self.lost += int(np.count_nonzero(~np.isin(np.unique(table_keys[must]), keys)))
        if self.reproducible:        # a merge of two key-ordered sequences
            history = carry_history(keys, table_keys, table_history, self.width)
        else:
            history = lookup(keys, table_keys, table_history, self.width)
        self.adopt(i, j, shifts, keys, history)
        if self.cell is not None:
            self.cell.strain_since_build = 0.0
        if (self.sort_rows and not self.scattered and e.n_owned >= SORT_MIN_ROWS
                and (self.scattered is None or self.builds % SORT_JUDGE_EVERY == 0)):
            self.scattered = scattered(self.i, self.j, e.x, e.n_owned, *self.grid_box(e.x[:e.n_owned]), self.cut)

    def adopt(self, i, j, shifts, keys, history):
        """Take a given list (rebuilds, and restarts on the same ranks: same order, same sums)."""
        self.i = np.ascontiguousarray(i, dtype=np.int32)
        self.j = np.ascontiguousarray(j, dtype=np.int32)
        self.shifts = np.ascontiguousarray(shifts, dtype=np.int8)
        self.keys = np.ascontiguousarray(keys, dtype=np.int64)
        self.history = np.ascontiguousarray(history, dtype=np.float64)
        self.shift = self.cell.shift_metres(self.shifts) if self.periodic else None
        self._crossing = crossing_rows(self.shifts) if self.periodic else None
        self._order = None
        self.builds += 1
        self.exact_ready = False

    def sort(self, elements, bonds=None):
        """Store the rows of a single process (no ghost rows) in spatial order, in place (module
        docstring), and relink ``bonds``; call before ``rebuild``. Nothing when ``sort_rows`` is
        off or the rows are in that order already."""
        e = elements
        if not self.sorting(e.n_owned) or e.n_owned != e.n_total or e.n_total < 2:
            return
        order = spatial_order(e.x, e.n_total, *self.grid_box(e.x[:e.n_total]), self.cut)
        if np.any(order != np.arange(e.n_total)):
            e.permute(order)
            if bonds is not None and bonds.n:
                bonds.relink(e.gid)

    def sorting(self, n_owned):
        """Whether a rank with ``n_owned`` owned rows keeps them in spatial order (and computes
        its pairs by first row): ``sort_rows``, at least ``SORT_MIN_ROWS`` rows, and rows found
        ``scattered`` at a list build (the judgement is per rank: the bits do not depend on it)."""
        return bool(self.sort_rows and self.reproducible and n_owned >= SORT_MIN_ROWS and self.scattered)

    def grid_box(self, x):
        """``(lo, hi)`` [3] [m] of the grid of the spatial order: the cell's box, or the extent of
        the positions ``x`` [n, 3] without a cell (the same on every rank with a cell)."""
        if self.cell is not None:
            return self.cell.lo, self.cell.hi
        return (x.min(axis=0), x.max(axis=0)) if len(x) else (np.zeros(3), np.zeros(3))

    def _compute_order(self, n_rows):
        """``compute``'s ``order`` argument of the current list (``pair_lists.compute_order``)."""
        order, inc_start, inc = compute_order(self.i, self.j, n_rows)
        shifts = np.ascontiguousarray(self.shifts[order])
        shift = None
        if self.shift is not None:
            shift = np.empty((len(order), 3))
            shift_metres_into(shifts, self.shift_period(), shift)
        self._order = (order, np.ascontiguousarray(self.i[order]), np.ascontiguousarray(self.j[order]),
                       shift, np.empty((len(order), 12)), inc_start, inc, shifts,
                       np.arange(len(order), dtype=np.int64), crossing_rows(shifts))

    def shift_period(self):
        """The cell's edges along its periodic axes, 0 along the others [3] [m]."""
        return np.where(self.cell.periodic, self.cell.length, 0.0)

    def budget_used(self, moved2):
        """True when the skin is used up: the largest displacement ``sqrt(moved2)`` [m] (fluctuation
        only, the affine part is in the cell's strain) plus the strain's change of pair distances
        exceeds ``skin / 2``."""
        strain = 0.0 if self.cell is None else self.cell.strain_since_build
        margin = 0.5 * self.skin - 0.5 * strain * max(self.cut, self.skin)
        return margin <= 0.0 or moved2 > margin * margin

    def needs_rebuild(self, elements, moved2=None):
        """Single-process check (the parallel layer reduces ``max_displacement2`` instead);
        ``moved2`` [m^2]: that displacement when the drift measured it."""
        if self.vl.builds == 0:
            return True
        if moved2 is None:
            moved2 = max_displacement2(elements.x, self.vl.x_build, elements.n_owned)
        return self.budget_used(moved2)

    def restore(self, elements, gid_i, gid_j, shifts, history, x_build=None):
        """Take back a stored list (gid ends in list order) on the rows of ``elements``; with
        ``x_build`` [n_owned, 3] (single process) the rebuild reference positions too."""
        e = elements
        order = np.argsort(e.gid, kind="stable")
        if len(gid_i) and len(order) == 0:
            raise ValueError("a stored contact's element is not held by this rank")
        top = max(len(order) - 1, 0)
        rows_i = order[np.minimum(np.searchsorted(e.gid[order], gid_i), top)] if len(order) else gid_i
        rows_j = order[np.minimum(np.searchsorted(e.gid[order], gid_j), top)] if len(order) else gid_j
        if len(gid_i) and (np.any(e.gid[rows_i] != gid_i) or np.any(e.gid[rows_j] != gid_j)):
            raise ValueError("a stored contact's element is not held by this rank")
        self.adopt(rows_i, rows_j, shifts, pair_keys(gid_i, gid_j), history)
        if x_build is not None:
            self.vl.x_build = np.array(x_build, dtype=np.float64)
            self.vl.n_owned = self.vl.n_total = e.n_owned
            self.vl.builds = 1

    def reference_positions(self):
        """Positions of the last build [n_total, 3] (mapped with the cell when it deforms)."""
        return self.vl.x_build

    # -- forces ---------------------------------------------------------------------------

    def compute(self, elements, dt, with_energy=True):
        """Add the contact forces to ``elements.f``, ``elements.t``; returns the energy [J] (NaN
        when not ``with_energy``: the step's energy is then not computed, nor the Love-Weber sums
        unless a servo reads them: ``stress_ready``)."""
        rate = None
        if self.periodic:
            if self.cell.deforming:
                if self.cell.tilted:    # H @ shifts, the tilt's terms grouped as the list search
                    self.shift[...] = self.cell.shift_metres(self.shifts)
                    if self._order is not None and self._order[3] is not None:
                        self._order[3][...] = self.cell.shift_metres(self._order[7])
                else:                   # in place: the same products as cell.shift_metres, on
                    period = self.shift_period()    # the rows across a boundary (the others are 0)
                    shift_metres_rows(self.shifts, period, self._crossing, self.shift)
                    if self._order is not None and self._order[3] is not None:
                        shift_metres_rows(self._order[7], period, self._order[9], self._order[3])
            rate = self.cell.gradient() if self.cell.sheared else self.cell.rate
        self.sums[:] = 0.0
        # exact sums when something may read them: a servo (every step), or an operation (the
        # steps with the energy, LAMMPS' eflag); the other steps keep the cheap register sums
        servo = self.cell is not None and self.cell.servo is not None
        self.exact_ready = False
        self.stress_ready = True
        order = {}
        if self.sorting(elements.n_owned):
            if self._order is None or len(self._order[0]) != len(self.i):
                self.history                # (back in list order, if it was not)
                self._compute_order(elements.n_total)
            # the history in computing order, kept so between steps: the loop then reads and
            # writes it in sequence (list order would read it at random)
            history = self._hist_c if self._hist_c is not None else self._history[self._order[0]]
            order = {"order": (self._order[8],) + self._order[1:7]}
        else:
            history = self.history
        if self.reproducible and (with_energy or servo):
            self.xacc[:] = 0
            flag = self.law.compute(self.params, elements, self.i, self.j, history, dt,
                                    self.shift, rate, self.sums, with_energy=with_energy,
                                    xacc=self.xacc, **order)
            if order:
                self._hist_c = history
            self.exact_ok = bool(flag == 0.0)
            self.exact_ready = True
            local = xa.value(self.xacc) if self.exact_ok else np.full(10, np.nan)
            self.sums[STRESS] = local[:9]     # this rank's share, rounded once (writers, checks)
            self.energy = float(local[9]) if with_energy else float("nan")
            return self.energy
        self.stress_ready = bool(with_energy or servo)
        self.energy = float(self.law.compute(self.params, elements, self.i, self.j, history,
                                             dt, self.shift, rate, self.sums,
                                             with_energy=with_energy,
                                             with_stress=self.stress_ready, **order))
        if order:
            self._hist_c = history
        return self.energy

    @property
    def n_touching(self):
        """This rank's number of pairs in contact at the last force evaluation (a float count)."""
        return self.sums[N_TOUCHING]

    def global_sums(self, comm):
        """The global Love-Weber sums [9] and contact energy [J] of the last force evaluation
        (collective): exact and the same bits on any number of ranks when ``reproducible`` (and
        the sums of the last evaluation are at hand, else the float sum of the per-rank shares,
        e.g. just after a restart); returns ``(sums [9], energy)``."""
        if self.reproducible and self.exact_ready:   # the same on every rank
            out = exact_sum.total(comm, self.xacc, self.exact_ok)
            return out[:9], float(out[9])
        if not self.stress_ready:
            raise RuntimeError("the Love-Weber sums were not computed at the last step (a step "
                               "without the energy, Simulation.step(with_energy=False)); compute "
                               "the forces with the energy before reading the stress")
        out = np.asarray(comm.sum(np.concatenate([self.sums[STRESS], [self.energy]])))
        return out[:9], float(out[9])

    def exact_state(self):
        """This rank's exact sums of the last force evaluation (JSON friendly: ``None`` when there
        are none, else ``[ok, limbs [10][NLIMB] ints]``), for a checkpoint's run state: a restart
        then reduces the same global sums as the uninterrupted run before its first step."""
        if not (self.reproducible and self.exact_ready):
            return None
        return [bool(self.exact_ok), self.xacc.tolist()]

    def restore_exact_state(self, states, rank, same):
        """Put back ``exact_state``: ``states`` is every writing rank's (a list), ``rank`` this
        rank; ``same``: the rank count is the one that wrote them (each rank takes its own), else
        rank 0 takes their exact total and the others zeros (the global sums keep their bits).
        Call on every rank."""
        if not self.reproducible or not states or any(s is None for s in states):
            self.exact_ready = False
            return
        if same:
            ok, limbs = states[rank]
            self.xacc[:] = np.asarray(limbs, dtype=np.int64)
        else:
            ok = all(bool(s[0]) for s in states)
            self.xacc[:] = 0
            if rank == 0:
                for s in states:
                    self.xacc += np.asarray(s[1], dtype=np.int64)   # limbs < 2^32: no overflow
                xa.normalize(self.xacc)
        self.exact_ok = bool(ok)
        self.exact_ready = True

    def stiffness(self, elements):
        """This rank's ``(omega2, kd2)`` of the listed pairs in contact (``timestep.contact_stiffness``):
        the bound of ``omega^2`` [1/s^2] of their normal springs over the owned rows (exact for
        frictionless contacts; the global bound is the maximum over the ranks) and the affine
        stiffness ``sum k |d|^2`` [N m] of the pairs counted here (the global one is the sum)."""
        e = elements
        k_constant, k_hertz = self.law.normal_stiffness(self.params)
        omega2, kd2 = contact_stiffness(self.i, self.j, NO_SHIFT if self.shift is None else self.shift,
                                        self.shift is not None, e.x, e.radius, e.mass, e.n_owned,
                                        k_constant, k_hertz)
        return float(omega2), float(kd2)

    def global_affine_stiffness(self, comm, elements):
        """The global ``kd2 = sum k |d|^2`` [N m] of ``stiffness`` (collective; exact, the same bits
        on any number of ranks, when ``reproducible``: it caps the pressure servo's gain)."""
        if not self.reproducible:
            return float(comm.sum(self.stiffness(elements)[1]))
        e = elements
        k_constant, k_hertz = self.law.normal_stiffness(self.params)
        acc = xa.zeros(1)
        ok = xa.affine_stiffness_terms(self.i, self.j, NO_SHIFT if self.shift is None else self.shift,
                                       self.shift is not None, e.x, e.radius, e.n_owned,
                                       float(k_constant), float(k_hertz), acc)
        return float(exact_sum.total(comm, acc, ok)[0])

    def nbytes(self):
        """Bytes held by this rank's contact list: pair rows, shifts, keys, history, the shifts in
        metres, the Verlet list's buffers (at capacity), its reference positions and scratch, and
        with sorted rows the computing order, its loads buffer and the history in that order."""
        arrays = [self.i, self.j, self.shifts, self.keys, self._history, self.vl._pairs,
                  self.vl._shifts, self.vl.x_build, self.xacc]
        if self.shift is not None:
            arrays.append(self.shift)
        if self._order is not None:      # the computing order of a sorted list and its buffers
            arrays += [a for a in self._order if a is not None]
        if self._hist_c is not None:
            arrays.append(self._hist_c)
        work = self.vl._work
        arrays += [work.cell_of, work.image, work.cell_rows, work.cell_start, work.xs, work.rs,
                   work.gs, work.ims]
        return int(sum(a.nbytes for a in arrays))

    def counted_once(self, n_owned):
        """Mask of the pairs this rank writes to files and sums (lower-gid end owned)."""
        return self.i < n_owned
