"""The flexible lateral membranes of a 2D biaxial test as a load fix.

``MembraneLoad`` (stage ``LOAD`` of ``pardem.engine.fixes``) keeps one chain per lateral side
(``pardem.physics.membrane.walk``: the outermost grains, from a bottom-platen grain to a
top-platen grain) and adds the confining pressure to its grains every force evaluation,
``f_k = p t (L1 n1 + L2 n2) / 2`` (``pardem.physics.membrane.forces``; ``t`` the thickness of the
2D stress convention).

Parallel: the chain grains may be owned by any rank. Each force evaluation every rank contributes
the positions of the chain grains it owns (``Communicator.allgatherv``: a few hundred floats), so
every rank holds the whole chain, computes the same forces from the same bits and adds those of its
owned grains: the load is the same on any number of ranks. The chains are rebuilt every
``rebuild_every`` steps, alternately from the bottom and from the top (``side_chain``: the walk of
``pardem.physics.membrane.walk`` with sharp convex tips turned round and dead ends left out), so
that grains can join or leave the membrane; a rebuild that finds no chain raises ValueError on
every rank (the same data).

A rebuild gathers only candidate grains (``Communicator.allgatherv`` of gids and positions), not
every grain: each rank preselects (``MembraneLoad.preselect``) both platens, the grains within
``PRESELECT_WIDTH`` r_m of the outermost grain of their band of height r_m (band extremes reduced
over the ranks) and those within ``PRESELECT_WIDTH`` r_m of the previous chains. Why this is
exact: the walk is local (``physics.membrane``, "Locality"): its decisions read the platens and
the grains within r_m of the grains it touched, in gid order. After the walk over the candidates
each rank checks its own grains left out against the touched grains; if none is within r_m of one
(on every rank), the candidates held everything the walk read, so by induction over its decisions
the walk over all grains makes the same ones: the same chains and skips, bit for bit. Otherwise
the preselection is widened round the first such touched grains in the walk's order (the walks
agree with the full ones before the first; after it a walk may wander) and the walk repeated: the
first faulty decision moves later every round, and after ``WIDEN_ROUNDS`` rounds every grain is
gathered. The preselection is only a guess; the check is what makes it exact.

The sample's area (``area``) is the polygon through the chains' centres closed by the platens. A
rebuild changes that outline without any grain moving (a grain joins the chain outside the old
one, or leaves it), so the area jumps by up to about a grain's area per change; the volumetric
strain must not see those jumps. Each rebuild therefore adds to ``area_offset`` the area of the
old outline minus that of the new, both at the positions of the rebuild's step, and
``tracked_area`` = ``area`` + ``area_offset`` changes only as the grains move.

State for a restart (``state`` / ``from_state``): the chains' gids, the rebuild count and step, the area offset;
with them the restarted run applies the same loads bit for bit (the chains do not depend on which
grains were gathered).
"""
import numpy as np

from pardem.engine.fixes import LOAD, ElementSelection, check_order
from pardem.physics import membrane

SIDES = membrane.SIDES      # ("left", "right")
MAX_SKIPS = 200             # walks a rebuild tries, each leaving out the previous one's dead end
PRESELECT_WIDTH = 3.0       # r_m: the band kept inside the lateral extremes and round the previous chains
WIDEN_ROUNDS = 16           # widenings of a preselection that missed grains, then all grains
WIDEN_DECISIONS = 8         # a widening covers the first faulty decision and those up to 8 after it
NEVER = np.iinfo(np.int64).max
MAX_BANDS = 1 << 16         # bands of the preselection (taller than r_m beyond: a grain flown far away)


def _walk_side(x, bottom, top, side, r_m, from_top):
    """``physics.membrane.walk`` as the rebuild uses it: tips turned round, MAX_SKIPS walks."""
    return membrane.walk(x, bottom, top, side, r_m, from_top=from_top, round_tips=True, attempts=MAX_SKIPS)


def _failure(side, r_m, w):
    return ValueError(f"the {side} membrane found no chain from platen to platen within r_m = {r_m:g} m "
                      f"(after leaving out {len(w.skipped)} grains): a gap in the side wider than r_m")


def side_chain(x, bottom, top, side, r_m, from_top=False):
    """The chain of ``side`` over positions ``x`` [n, 2] (indices, bottom -> top) and the indices
    of the grains it had to leave out: ``physics.membrane.walk`` from the bottom platen (or, with
    ``from_top``, from the top one), sharp convex tips turned round, a dead end left out and the
    walk repeated (up to ``MAX_SKIPS`` walks). ValueError if no walk reaches the other platen."""
    w = _walk_side(x, bottom, top, side, r_m, from_top)
    if not w.reached:
        raise _failure(side, r_m, w)
    return w.links, w.skipped


class MembraneLoad:
    """Confining pressure ``pressure`` [Pa] on both lateral sides, over ``thickness`` [m].

    bottom_gids, top_gids : the gids of the two platens' grains; r_m [m] : the chain's search
    distance; rebuild_every : steps between chain rebuilds (0: never after the first).
    After each force evaluation (same on every rank): ``chains`` {side: gids [m]}, ``positions``
    {side: [m, 2] m}, ``forces`` {side: [m, 2] N}, ``total`` {side: [2] N}.
    """
    stage = LOAD

    def __init__(self, bottom_gids, top_gids, pressure, thickness, r_m, rebuild_every=100):
        self.bottom = np.unique(np.asarray(bottom_gids, dtype=np.int64))
        self.top = np.unique(np.asarray(top_gids, dtype=np.int64))
        if not len(self.bottom) or not len(self.top):
            raise ValueError("the membrane needs grains in both platens (bottom_gids, top_gids)")
        for name, v in (("pressure", pressure), ("thickness", thickness), ("r_m", r_m)):
            if not (np.isfinite(float(v)) and float(v) >= 0.0):
                raise ValueError(f"{name} = {v!r}: expected a finite value >= 0")
        if not float(r_m) > 0.0 or not float(thickness) > 0.0:
            raise ValueError("r_m and thickness must be > 0 [m]")
        if int(rebuild_every) < 0:
            raise ValueError(f"rebuild_every = {rebuild_every!r}: expected steps >= 0")
        self.pressure = float(pressure)
        self.thickness = float(thickness)
        self.r_m = float(r_m)
        self.rebuild_every = int(rebuild_every)
        self.chains = None
        self.skipped = {s: np.zeros(0, np.int64) for s in SIDES}   # grains the last rebuild left out
        self.rebuilds = 0
        self.area_offset = 0.0      # [m^2] the outline changes of the rebuilds (tracked_area)
        self.built_at = -1
        self.gathered = 0           # grains the last rebuild gathered, and its widening rounds
        self.widened = 0
        self._selection = None
        self.positions = {}
        self.forces = {}
        self.total = {}
        self._order_checked = None

    # -- chains ------------------------------------------------------------------------------

    def preselect(self, sim):
        """Mask [n_owned] of this rank's candidate grains for a rebuild (collective; module
        docstring): both platens, the grains within PRESELECT_WIDTH r_m inside the lateral
        extremes of their band (height r_m) and round the previous chains' grains."""
        e, n = sim.elements, sim.elements.n_owned
        gid, x, y = e.gid[:n], e.x[:n, 0], e.x[:n, 1]
        r, w = self.r_m, PRESELECT_WIDTH * self.r_m
        keep = np.isin(gid, self.bottom) | np.isin(gid, self.top)
        lim = sim.comm.max_array([y.max() if n else -np.inf, -y.min() if n else -np.inf])
        y0, span = -lim[1], lim[0] + lim[1]
        if not np.isfinite(span):
            return np.ones(n, dtype=bool)       # no grains, or non-finite ones: gather all (the walk judges)
        nb = int(min(span / r, MAX_BANDS - 1)) + 1
        h = max(r, span / nb) * (1.0 + 1e-12)
        band = np.clip(((y - y0) / h).astype(np.int64), 0, nb - 1)
        ext = np.full((2, nb), -np.inf)
        np.maximum.at(ext[0], band, x)
        np.maximum.at(ext[1], band, -x)
        ext = sim.comm.max_array(ext)
        keep |= (x >= ext[0][band] - w) | (-x >= ext[1][band] - w)
        pos = self.positions
        if not pos and self.chains is not None:
            pos = self.gather_positions(sim)        # a restart: chains known, positions not yet
        if pos:
            keep |= membrane.within(e.x[:n], np.vstack([pos[s] for s in SIDES]), w)
        return keep

    def rebuild(self, sim):
        """Rebuild both chains (collective), from the bottom on even rebuilds and from the top on
        odd ones, from the gathered candidate grains (module docstring). Sets ``gathered`` (grains
        gathered by the last walk) and ``widened`` (its widening rounds)."""
        e, n = sim.elements, sim.elements.n_owned
        own_gid, own_x = e.gid[:n], np.ascontiguousarray(e.x[:n, :2])
        from_top = self.rebuilds % 2 == 1
        area_before = None if self.chains is None else enclosed_area(self.gather_positions(sim))
        keep = self.preselect(sim)
        for round_ in range(WIDEN_ROUNDS + 2):
            if round_ == WIDEN_ROUNDS + 1:
                keep[:] = True                      # the last resort: every grain
            gid = sim.comm.allgatherv(np.ascontiguousarray(own_gid[keep], dtype=np.int64))
            x = sim.comm.allgatherv(own_x[keep])
            o = np.argsort(gid, kind="stable")      # gid order: the walk's order whatever was gathered
            gid, x = gid[o], x[o]
            bottom, top = np.isin(gid, self.bottom), np.isin(gid, self.top)
            walks = {side: _walk_side(x, bottom, top, side, self.r_m, from_top) for side in SIDES}
            # per side, the first decision that read near a grain this rank left out (a hair over
            # r_m: the walk compares d^2 with r_m^2, this hypot with r_m; erring wide only costs
            # a widening): the walks agree with those over all grains before it
            left_out = own_x[~keep]
            first, bad = {}, {}
            for side in SIDES:
                t = np.nonzero(walks[side].touched)[0]
                bad[side] = t[membrane.within(x[t], left_out, self.r_m * (1.0 + 1e-9))]
                first[side] = sim.comm.min(int(walks[side].order[bad[side]].min()) if len(bad[side]) else NEVER)
            if all(first[side] == NEVER for side in SIDES):
                break
            # widen round this rank's faulty decisions shortly after the first (later ones come
            # from a walk gone wrong, which wanders: widening round all would gather most grains);
            # the first faulty decision moves on every round
            for side in SIDES:
                o = walks[side].order[bad[side]]
                at = bad[side][o <= first[side] + WIDEN_DECISIONS]
                if len(at):
                    keep |= membrane.within(own_x, x[at], PRESELECT_WIDTH * self.r_m)
        self.gathered, self.widened = len(gid), round_
        chains = {}
        self.skipped = {}
        for side in SIDES:
            w = walks[side]
            if not w.reached:
                raise _failure(side, self.r_m, w)
            chains[side] = gid[w.links]
            self.skipped[side] = gid[w.skipped]
        self.set_chains(chains)
        if area_before is not None:
            # the outline changed, the grains did not move: carry the difference (module
            # docstring); the new chains' positions are among the gathered ones
            self.area_offset += area_before - enclosed_area({s: x[walks[s].links] for s in SIDES})
        self.rebuilds += 1
        self.built_at = sim.step_count

    def set_chains(self, chains):
        self.chains = {s: np.asarray(chains[s], dtype=np.int64) for s in SIDES}
        self._selection = ElementSelection(np.concatenate([self.chains[s] for s in SIDES]), "membrane gids")

    def gather_positions(self, sim):
        """{side: [m, 2]} positions of the chains' grains (collective, the same on every rank)."""
        e = sim.elements
        rows, idx = self._selection.rows(e, sim.comm)
        # two allgatherv (no pickling): each rank's chain indices, then their positions
        where = sim.comm.allgatherv(np.ascontiguousarray(idx, dtype=np.int64))
        found = sim.comm.allgatherv(np.ascontiguousarray(e.x[rows, :2], dtype=np.float64))
        x = np.empty((len(self._selection.gids), 2))
        x[where] = found
        m = len(self.chains[SIDES[0]])
        return {SIDES[0]: x[:m], SIDES[1]: x[m:]}

    # -- the fix -----------------------------------------------------------------------------

    def post_force(self, sim):
        key = tuple(map(id, sim.fixes))
        if self._order_checked != key:
            check_order(sim, self)
            self._order_checked = key
        step = sim.step_count
        if self.chains is None or (self.rebuild_every and step % self.rebuild_every == 0
                                   and step != self.built_at):
            self.rebuild(sim)
        pos = self.gather_positions(sim)
        forces = {s: membrane.forces(pos[s], np.arange(len(pos[s])), s, self.pressure, self.thickness)
                  for s in SIDES}
        self.positions, self.forces = pos, forces
        self.total = {s: forces[s].sum(axis=0) for s in SIDES}
        e = sim.elements
        rows, idx = self._selection.rows(e, sim.comm)
        if len(rows):
            both = np.concatenate([forces[s] for s in SIDES])
            e.f[rows, :2] += both[idx]

    # -- measures and restart --------------------------------------------------------------

    def polygon(self):
        """The sample outline [k, 2] [m] through the membrane grains' centres: the right chain
        bottom -> top, then the left chain top -> bottom (counter-clockwise)."""
        return outline(self.positions)

    def area(self):
        """Area [m^2] enclosed by ``polygon`` (shoelace; the platens close it between the chains' ends)."""
        return enclosed_area(self.positions)

    def tracked_area(self):
        """``area()`` plus ``area_offset`` [m^2]: the area whose changes are the sample's
        deformation only, continuous across the rebuilds (the volumetric strain's; module
        docstring)."""
        return self.area() + self.area_offset

    def state(self):
        """JSON-friendly state for a checkpoint (with the constructor's arguments)."""
        return {"bottom": self.bottom.tolist(), "top": self.top.tolist(), "pressure": self.pressure,
                "thickness": self.thickness, "r_m": self.r_m, "rebuild_every": self.rebuild_every,
                "chains": None if self.chains is None else {s: self.chains[s].tolist() for s in SIDES},
                "rebuilds": self.rebuilds, "built_at": self.built_at, "area_offset": self.area_offset}

    @classmethod
    def from_state(cls, s):
        m = cls(s["bottom"], s["top"], s["pressure"], s["thickness"], s["r_m"], s["rebuild_every"])
        if s["chains"] is not None:
            m.set_chains(s["chains"])
        m.rebuilds = int(s["rebuilds"])
        m.built_at = int(s["built_at"])
        m.area_offset = float(s.get("area_offset", 0.0))   # absent from checkpoints before it
        return m


def outline(positions):
    """The polygon [k, 2] [m] through the chains' centres ``positions`` ({side: [m, 2]}): the
    right chain bottom -> top, then the left chain top -> bottom (counter-clockwise)."""
    return np.vstack([positions["right"], positions["left"][::-1]])


def enclosed_area(positions):
    """Area [m^2] of ``outline(positions)`` (shoelace; the platens close it between the chains' ends)."""
    p = outline(positions)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


__all__ = ["MembraneLoad", "SIDES", "enclosed_area"]
