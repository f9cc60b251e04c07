"""Communication between slabs: migration, ghost layers and the per-step ghost refresh.

Verbs (LAMMPS style; only ``Simulation.step`` and the setup call them):

* ``exchange``: owned elements whose key left the slab move to their owner with the bonds they take
  part in (bond state travels whole: reference vectors, stiffness, later plastic strain); every
  per-element array of ``Elements.pack`` travels, the custom ones (``Elements.properties``) too;
* ``borders``: each rank sends the neighbours its elements within ``ghost_range`` (along the slab
  axis) of the neighbour's nearest owned element; they become ghost rows after the owned rows, and
  bonds are relinked by global id;
* ``forward``: every step, positions, velocities, angular velocities and orientations of the ghost
  rows are refreshed with non-blocking point-to-point messages to the two neighbours only.

Bond scheme: a rank computes every bond that has at least one owned end, and keeps the forces on its
owned rows only (ghost rows are zeroed each step). A bond crossing a boundary is thus computed on
both sides, from bitwise-identical inputs (ghosts are exact copies) and in the same orientation
(ends ordered by gid), so both sides apply exactly opposite forces. We chose this over reverse
communication of ghost forces because it needs one message per neighbour per step instead of two,
and because bond state updates (plasticity, rupture) then happen identically on both sides with no
extra message; the price is computing the boundary bonds twice, a fraction ``~ range / slab width``.

Rebuilds (exchange + borders) happen when an owned element has moved more than half the skin since
the last one, or when the load balance is re-done; in between, ghosts are valid because every
element that can interact with an owned one was within ``ghost_range = interaction + skin``.

Contacts: at a rebuild the contact history table (pairs with a non-zero history, keyed by their
end gids) travels with the migrating elements like the bonds do, then the contact list is rebuilt
on the new rows (``pardem.engine.contacts``).

Reproducible runs (``Contacts.reproducible``): the load balance is checked only
at the rebuilds the displacement criterion asks for (at least ``balance_every`` steps apart), never
forcing a rebuild of its own, so that lists are rebuilt (and positions wrapped) at the same steps on
any number of ranks.

Periodic slab axis (a ``PeriodicCell`` periodic along it): the first and last ranks are
neighbours; positions are wrapped into the cell at each rebuild; an element leaving a slab goes the
short way round; with two ranks, the single neighbour gets the union of both boundary layers once
(the neighbour list finds the right periodic image by itself).
"""
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from pardem.parallel.slabs import Slabs, imbalance
from pardem.physics.neighbours import max_displacement2
from pardem.physics.pair_lists import spatial_order
from pardem.errors import DecompositionError, InstabilityError
from pardem.engine.state import Bonds, Elements

_TAG_FORWARD, _TAG_EXCHANGE, _TAG_BORDERS = 71, 72, 73
GHOST_WIDTH = 13   # doubles per ghost per step: x, v, w (3 each), q (4)
GHOST_WIDTH_NO_BONDS = 9   # x, v, w: without bonds no kernel reads a ghost's orientation


@njit(cache=True, error_model="numpy")
def _pack_forward(x, v, w, q, rows, buf):
    for k in range(rows.shape[0]):
        r = rows[k]
        for d in range(3):
            buf[k, d] = x[r, d]
            buf[k, 3 + d] = v[r, d]
            buf[k, 6 + d] = w[r, d]
        if buf.shape[1] > 9:
            for d in range(4):
                buf[k, 9 + d] = q[r, d]


@njit(cache=True, error_model="numpy")
def _unpack_forward(buf, start, x, v, w, q):
    for k in range(buf.shape[0]):
        r = start + k
        for d in range(3):
            x[r, d] = buf[k, d]
            v[r, d] = buf[k, 3 + d]
            w[r, d] = buf[k, 6 + d]
        if buf.shape[1] > 9:
            for d in range(4):
                q[r, d] = buf[k, 9 + d]


@dataclass
class SlabUpdate:
    """What ``SlabComm.update`` did: the rank's elements and bonds after it (new objects after a
    rebuild), whether it rebuilt the ghosts (and contact list), and whether some rank blew up."""
    elements: Elements
    bonds: Bonds
    rebuilt: bool
    unstable: bool


def rank_report(rank, elements, bonds, seconds_computing, seconds_communicating=0.0, rebuilds=0,
                rebalances=0):
    """One rank's row of the per-rank table of a run summary (plain numbers)."""
    return {"rank": int(rank), "owned_elements": int(elements.n_owned),
            "ghost_elements": int(elements.n_total - elements.n_owned), "bonds_held": int(bonds.n),
            "seconds_computing": float(seconds_computing),
            "seconds_communicating": float(seconds_communicating),
            "rebuilds": int(rebuilds), "rebalances": int(rebalances)}


def _select(arrays, rows):
    return {k: v[rows] for k, v in arrays.items()}


def _concat(parts):
    """Join pack dicts. Parts without rows are left out (a rank without bonds packs a zero-width
    ``rot_damping``); a ``rot_damping`` that not every part carries is dropped ([n, 0]: the bonds
    recompute it, ``pardem.physics.beam.compute_bonds``)."""
    full = [p for p in parts if len(next(iter(p.values())))] or parts[:1]
    out = {}
    for k in full[0]:
        arrays = [p[k] for p in full]
        if k == "rot_damping" and len({a.shape[1:] for a in arrays}) > 1:
            out[k] = np.zeros((sum(len(a) for a in arrays), 0))
        else:
            out[k] = np.concatenate(arrays)
    return out




def _gaps(s, lo, hi):
    """(lower, upper) [m]: how far the owned rows' coordinates ``s`` stay inside the slab
    ``[lo, hi]`` (0 without owned rows: a neighbour then sends what reaches the bound)."""
    if len(s) == 0:
        return 0.0, 0.0
    return max(float(s.min()) - lo, 0.0), max(hi - float(s.max()), 0.0)


class BondOutOfReach(DecompositionError):
    """A bond's ends are farther apart than the ghost range (raised on every rank together)."""


class SlabComm:
    """Slab decomposition of one ``Simulation``'s elements and bonds over ``comm``.

    ghost_range [m]: interaction range plus skin; skin [m]: allowed displacement budget between
    rebuilds (rebuild when an element moved more than skin / 2). Load balance is checked every
    ``balance_every`` steps; slabs are re-cut when the imbalance of the owned counts (``balance_by =
    "count"``) or of the measured computing seconds (``"time"``) exceeds ``threshold``.
    """

    def __init__(self, comm, slabs, ghost_range, skin, balance_every=200, threshold=0.05,
                 balance_by="count", cell=None):
        self.comm = comm
        self.mpi = comm.comm
        self.slabs = slabs
        self.ghost_range = float(ghost_range)
        self.skin = float(skin)
        self.balance_every = int(balance_every)
        self.threshold = float(threshold)
        self.balance_by = balance_by
        r, P = comm.rank, comm.size
        self.cell = cell
        self._check_shear()
        self.periodic = cell is not None and bool(cell.periodic[slabs.axis]) and P > 1
        if self.periodic:
            self.left, self.right = (r - 1) % P, (r + 1) % P
        else:
            self.left = r - 1 if r > 0 else None
            self.right = r + 1 if r < P - 1 else None
        self.neighbours = sorted({n for n in (self.left, self.right) if n is not None})
        self.send_rows = {}
        self.recv_start = {}
        self.recv_count = {}
        self._send_buf = {}
        self._recv_buf = {}
        self.forward_orientation = True
        self.x_build = None
        self.seconds_communicating = 0.0
        self.rebuilds = 0
        self.rebalances = 0
        self._compute_mark = 0.0
        self._balance_checked = 0      # step of the last balance check (reproducible runs)
        # without contacts (bonds only), whether re-cuts wait for a displacement rebuild; with
        # contacts their ``reproducible`` decides
        self.reproducible = cell is not None

    # -- setup and rebuilds -------------------------------------------------------------------

    def setup(self, elements, bonds):
        """Migrate, build ghosts and relink: returns the new (elements, bonds)."""
        elements, bonds, _ = self.exchange(elements, bonds)
        return self.borders(elements, bonds)

    def setup_with_pairs(self, elements, bonds, table, wrap=True, contacts=None):
        """``setup`` that also migrates the contact history ``table``; returns (elements, bonds,
        table) with the table entries touching an owned element. ``wrap``: first wrap the owned
        rows into the cell (False when the caller just did: a second wrap may move a row that
        the first rounded onto the cell's upper face, which one process would not do).
        ``contacts``: the owned rows are stored in its spatial order when its ``sort_rows``
        (else by gid)."""
        if wrap and self.cell is not None:
            self.cell.wrap(elements)
        elements, bonds, table = self.exchange(elements, bonds, table, contacts)
        elements, bonds = self.borders(elements, bonds)
        return elements, bonds, table

    def _destinations(self, owner):
        """{neighbour: mask} of the owned rows to send each way (``None``: left the domain)."""
        r = self.comm.rank
        if not self.periodic:
            return {self.left: owner < r, self.right: owner > r}
        d = (owner - r) % self.comm.size
        right = (d > 0) & (d <= self.comm.size // 2)
        left = d > self.comm.size // 2
        if self.left == self.right:
            return {self.left: left | right}
        return {self.left: left, self.right: right}

    def _key(self, e, n):
        return e.x[:n, self.slabs.axis], e.gid[:n]

    def exchange(self, elements, bonds, table=None, contacts=None):
        """Move owned elements (with their bonds and contact history) to the ranks owning their
        keys; drop ghosts.

        Returns owned-only elements sorted by gid (in the spatial order of ``contacts`` when its
        ``sort_rows``: ``pardem.engine.contacts``), the bonds with at least one owned end (``i, j``
        not yet linked: ``borders`` does it) and the entries of ``table`` (gid_i, gid_j, ...) with
        at least one owned end (None when ``table`` is None).
        """
        axis = self.slabs.axis
        cur = elements.pack(slice(0, elements.n_owned))
        cur_bonds = bonds.pack(slice(0, bonds.n))
        for _ in range(self.comm.size):
            owner = self.slabs.owner(cur["x"][:, axis], cur["gid"])
            go = self._destinations(owner)
            if not self.comm.any(np.any(owner != self.comm.rank)):
                break
            if go.pop(None, np.zeros(0, bool)).any():
                raise DecompositionError("an element left the domain of all slabs")
            out = {}
            for nb, mask in go.items():
                gids = cur["gid"][mask]
                touch = np.isin(cur_bonds["gid_i"], gids) | np.isin(cur_bonds["gid_j"], gids)
                sent = None
                if table is not None:
                    sent = _select(table, np.isin(table["gid_i"], gids) | np.isin(table["gid_j"], gids))
                out[nb] = (_select(cur, mask), _select(cur_bonds, touch), sent)
            got = [g for g in self._swap(out, _TAG_EXCHANGE).values() if g is not None]
            cur = _concat([_select(cur, owner == self.comm.rank)] + [g[0] for g in got])
            cur_bonds = _concat([cur_bonds] + [g[1] for g in got])
            if table is not None:
                table = _concat([table] + [g[2] for g in got])
        else:
            raise DecompositionError("elements still misplaced after one pass per rank")
        order = np.argsort(cur["gid"], kind="stable")
        if contacts is not None and contacts.sorting(len(order)) and len(order) > 1:
            x = cur["x"][order]      # from gid order: the same order whatever the arrival order
            order = order[spatial_order(x, len(x), *contacts.grid_box(x), contacts.cut)]
        cur = _select(cur, order)
        mine = np.isin(cur_bonds["gid_i"], cur["gid"]) | np.isin(cur_bonds["gid_j"], cur["gid"])
        if table is not None:
            table = _select(table, np.isin(table["gid_i"], cur["gid"]) | np.isin(table["gid_j"], cur["gid"]))
        return (Elements.unpack([cur], len(cur["gid"])), Bonds.unpack([_select(cur_bonds, mine)], **bonds.flags()),
                table)

    def _swap(self, out, tag):
        """Send ``out[neighbour]`` (pickled; None if absent) to each neighbour and receive what it
        sent: {neighbour: object}. Used at rebuilds only; the per-step exchange is ``forward``."""
        reqs = [self.mpi.isend(out.get(nb), dest=nb, tag=tag) for nb in self.neighbours]
        got = {nb: self.mpi.recv(source=nb, tag=tag) for nb in self.neighbours}
        for r in reqs:
            r.wait()
        return got

    def _check_shear(self):
        """ValueError when the cell's shear or tilt moves the slab coordinate with another axis (x
        with y under xy shear): the ghosts, selected by that coordinate alone, could miss a
        tilted image (``PeriodicCell.slab_axis_allowed``)."""
        c = self.cell
        if c is not None and self.comm.size > 1 and (c.sheared or c.tilted) \
                and not c.slab_axis_allowed(self.slabs.axis):
            raise ValueError(f"slab axis {self.slabs.axis}: the cell's shear moves the "
                             f"{'xyz'[self.slabs.axis]} coordinates with another axis; cut the slabs "
                             "along an axis it does not move (y or z for xy shear)")

    def follow_cell(self, factor):
        """Map the slab cuts with the cell's affine step (``factor`` [3]), so that the slabs keep
        their elements and relative widths while the cell deforms (the same on every rank)."""
        if self.cell is not None and self.cell.sheared:
            self._check_shear()
        a = self.slabs.axis
        if self.cell is not None and factor[a] != 1.0:
            lo = self.cell.lo[a]
            self.slabs.cut_s = lo + (np.asarray(self.slabs.cut_s) - lo) * factor[a]

    def _bounds(self, rank):
        lo, hi = self.slabs.bounds(rank)
        if self.periodic:   # the end slabs stop at the cell's faces
            a = self.slabs.axis
            lo, hi = max(lo, self.cell.lo[a]), min(hi, self.cell.hi[a])
        return lo, hi

    def _narrowest(self):
        if not self.periodic:
            return self.slabs.narrowest_interior()
        return min(np.subtract(*self._bounds(r)[::-1]) for r in range(self.comm.size))

    def borders(self, elements, bonds, extra=0.0):
        """Ghost rows from the neighbours within ``ghost_range`` (+ ``extra`` [m]) of each boundary;
        relinks bonds. (A restart takes ``extra = skin`` to hold every partner of a stored contact
        list whatever the elements did since its build.)"""
        e = elements
        n = e.n_owned
        if self._narrowest() < self.ghost_range:
            raise DecompositionError(
                f"a slab is {self._narrowest():.4g} m thin, less than the ghost range "
                f"{self.ghost_range:.4g} m: use fewer ranks for this domain")
        lo, hi = self._bounds(self.comm.rank)
        s = e.x[:n, self.slabs.axis]
        reach = self.ghost_range + extra
        # a row is sent only if it lies within reach of the neighbour's nearest owned row, not
        # merely of the cut: a balanced cut lies on a lattice plane, and ``s < lo + reach`` then
        # sent a second plane that no owned row can reach (a third of the ghosts, and a rank
        # with more ghosts than the other, at n = 60 on 2 ranks)
        gaps = self.comm.allgather(_gaps(s, lo, hi))
        rows = {}
        if self.left is not None:
            rows[self.left] = np.nonzero(s < lo + (reach - gaps[self.left][1]))[0]
        if self.right is not None:
            right = np.nonzero(s >= hi - (reach - gaps[self.right][0]))[0]
            rows[self.right] = np.union1d(rows[self.right], right) if self.right == self.left else right
        got = self._swap({nb: e.pack(r) for nb, r in rows.items()}, _TAG_BORDERS)
        parts = [e.pack(slice(0, n))]
        start = n
        self.send_rows, self.recv_start, self.recv_count = {}, {}, {}
        for nb in self.neighbours:
            self.send_rows[nb] = rows[nb].astype(np.int64)
            part = got[nb]
            self.recv_start[nb] = start
            self.recv_count[nb] = len(part["gid"])
            start += len(part["gid"])
            parts.append(part)
        new = Elements.unpack(parts, n)
        try:
            bonds.relink(new.gid)
            missing = None
        except KeyError as err:
            missing = err.args[0]
        if self.comm.any(missing is not None):     # every rank raises together
            raise BondOutOfReach(f"{missing or 'a bond end is missing on another rank'}: a bond is "
                                 f"longer than the ghost range {self.ghost_range:.4g} m")
        # the ghosts' orientations serve the bond kernels only: refreshed every step while some
        # rank has bonds, else sent with the ghosts at this rebuild only
        self.forward_orientation = self.comm.any(bonds.n > 0)
        width = GHOST_WIDTH if self.forward_orientation else GHOST_WIDTH_NO_BONDS
        self._send_buf = {nb: np.empty((len(self.send_rows[nb]), width)) for nb in self.neighbours}
        self._recv_buf = {nb: np.empty((self.recv_count[nb], width)) for nb in self.neighbours}
        self.x_build = new.x[:n].copy()
        return new, bonds

    # -- every step ---------------------------------------------------------------------------

    def forward(self, e):
        """Refresh the ghost rows' x, v, w from their owners, and q while there are bonds
        (``forward_orientation``)."""
        reqs = []
        for nb in self.neighbours:
            if self.recv_count[nb]:
                reqs.append(self.mpi.Irecv(self._recv_buf[nb], source=nb, tag=_TAG_FORWARD))
        for nb in self.neighbours:
            if len(self.send_rows[nb]):
                _pack_forward(e.x, e.v, e.w, e.q, self.send_rows[nb], self._send_buf[nb])
                reqs.append(self.mpi.Isend(self._send_buf[nb], dest=nb, tag=_TAG_FORWARD))
        self.comm.waitall(reqs)
        for nb in self.neighbours:
            if self.recv_count[nb]:
                _unpack_forward(self._recv_buf[nb], self.recv_start[nb], e.x, e.v, e.w, e.q)

    def update(self, step, elements, bonds, contacts=None, pairs_freed=False, unstable=False,
               seconds_computing=0.0, moved2=None):
        """After the drift of ``step``: rebuild (and rebalance) or refresh the ghosts. Collective.

        ``contacts``: the rank's ``Contacts`` (rebuilt here with the histories that travelled);
        ``pairs_freed``: a bond broke on this rank since the last rebuild; ``unstable``: this rank
        blew up (every rank then stops together instead of rebuilding around NaN positions);
        ``seconds_computing``: this rank's kernel seconds so far (time-based balance);
        ``moved2`` [m^2]: the owned rows' largest squared displacement from ``x_build`` when the
        drift measured it (``verlet.kick_drift``), else measured here.
        Returns ``SlabUpdate``: the (possibly new) elements and bonds, and what happened.
        """
        t0 = time.perf_counter()
        e = elements
        reproducible = self.reproducible if contacts is None else contacts.reproducible
        rebalance = (not reproducible and self.balance_every > 0 and step % self.balance_every == 0
                     and self._unbalanced(e.n_owned, seconds_computing))
        if unstable:
            moved = np.inf
        else:
            moved = max_displacement2(e.x, self.x_build, e.n_owned) if moved2 is None else moved2
        # a broken bond (on any rank) frees a pair for the contact list: rebuild it now
        moved, freed = self.comm.max_array([moved, contacts is not None and pairs_freed])
        if not np.isfinite(moved):
            self.seconds_communicating += time.perf_counter() - t0
            return SlabUpdate(elements, bonds, rebuilt=False, unstable=True)
        used = contacts.budget_used(moved) if contacts is not None else moved > (0.5 * self.skin) ** 2
        if (reproducible and (used or freed) and self.balance_every > 0
                and step - self._balance_checked >= self.balance_every):
            # reproducible runs re-cut only at the rebuilds one process would make too: a rebuild
            # wraps positions into the cell and restarts the skin budget, so an extra one would
            # change the trajectory's bits
            self._balance_checked = step
            rebalance = self._unbalanced(e.n_owned, seconds_computing)
        rebuilt = bool(rebalance or used or freed)
        if rebuilt:
            if self.cell is not None:
                self.cell.wrap(e)
            if rebalance:
                self._recut(e, seconds_computing)
            try:
                if contacts is None:
                    elements, bonds = self.setup(e, bonds)
                else:
                    elements, bonds, table = self.setup_with_pairs(e, bonds, contacts.table(),
                                                                   wrap=False, contacts=contacts)
                    contacts.rebuild(elements, bonds, table)
            except BondOutOfReach as err:
                # during a run a bond stretched by a quarter of its length means the motion blew up
                raise InstabilityError(f"at step {step}: {err}") from None
            self.rebuilds += 1
        else:
            self.forward(e)
        self.seconds_communicating += time.perf_counter() - t0
        return SlabUpdate(elements, bonds, rebuilt=rebuilt, unstable=False)

    # -- load balance -------------------------------------------------------------------------

    def _loads(self, n_owned, seconds_computing):
        if self.balance_by == "time":
            busy = seconds_computing - self._compute_mark
            return np.array(self.comm.allgather(busy))
        return np.array(self.comm.allgather(n_owned), dtype=float)

    def _unbalanced(self, n_owned, seconds_computing):
        loads = self._loads(n_owned, seconds_computing)
        self._last_loads = loads
        return imbalance(loads) > self.threshold

    def _recut(self, e, seconds_computing):
        n = e.n_owned
        weights = None
        if self.balance_by == "time":
            per_element = self._last_loads[self.comm.rank] / max(n, 1)
            weights = np.full(n, per_element)
        self.slabs = Slabs.balanced(self.comm, self.slabs.axis, e.x[:n, self.slabs.axis], e.gid[:n], weights)
        self._compute_mark = seconds_computing
        self.rebalances += 1

    def report(self, elements, bonds, seconds_computing):
        """Per-rank table (list of dicts on every rank): owned, ghosts, computing and comm seconds."""
        return self.comm.allgather(rank_report(self.comm.rank, elements, bonds, seconds_computing,
                                               self.seconds_communicating, self.rebuilds, self.rebalances))
