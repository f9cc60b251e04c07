"""The flexible lateral membranes of a 2D biaxial test as a load fix (issue 13, item 3).

``MembraneLoad`` (stage ``LOAD`` of ``pardem.engine.fixes``) keeps one chain per lateral side
(``pardem.physics.membrane.chain``: the outermost grains, from a bottom-platen grain to a
top-platen grain) and adds the confining pressure to its grains every force evaluation,
``f_k = p t (L1 n1 + L2 n2) / 2`` (``pardem.physics.membrane.forces``; ``t`` the thickness of the
2D stress convention).

Parallel: the chain grains may be owned by any rank. Each force evaluation every rank contributes
the positions of the chain grains it owns (``Communicator.allgather``: a few hundred floats), so
every rank holds the whole chain, computes the same forces from the same bits and adds those of its
owned grains: the load is the same on any number of ranks. The chains are rebuilt every
``rebuild_every`` steps from the gathered positions of all grains, alternately from the bottom and
from the top (the walk from the top is the walk of the mirror image y -> -y, reversed), so that
grains can join or leave the membrane (``side_chain``; its walk also turns round sharp convex
tips of the boundary, which ``physics.membrane.chain`` stops on); a rebuild that finds no chain raises ValueError on every rank (the same data).

State for a restart (``state`` / ``from_state``): the chains' gids, the rebuild count and step;
with them the restarted run applies the same loads bit for bit.
"""
import numpy as np

from pardem.engine.fixes import LOAD, ElementSelection, _check_order
from pardem.physics import membrane

SIDES = membrane.SIDES      # ("left", "right")
MAX_SKIPS = 200             # grains a chain may leave out before a rebuild gives up


def _walk(xs, ys, start, excluded, top, r_m):
    """``pardem.physics.membrane``'s walk (gift wrapping within ``r_m``: the candidate furthest
    outward by angle, then by distance), except that a left turn of more than 90 degrees is
    allowed, ranked after every other candidate: the walk then goes round a sharp convex tip of
    the boundary instead of stopping on it (physics.membrane refuses those turns). A Python loop
    over the chain's links (vectorised over the grains), run at rebuilds only. Returns
    ``(links, reached)``."""
    used = excluded.copy()
    used[start] = True
    links = [int(start)]
    p = int(start)
    dx, dy = 0.0, 1.0
    r2 = r_m * r_m
    for _ in range(len(xs)):
        vx, vy = xs - xs[p], ys - ys[p]
        d2 = vx * vx + vy * vy
        ok = ~used & (d2 <= r2) & (d2 > 0.0)
        if not ok.any():
            return np.asarray(links, dtype=np.int64), False
        q = np.nonzero(ok)[0]
        sx, sy = dy, -dx
        a = np.arctan2(sx * vy[q] - sy * vx[q], sx * vx[q] + sy * vy[q])
        a = np.where(a < -np.pi + 1e-9, np.pi, a)          # straight back: +pi, as the physics walk
        a = np.where(a <= -0.5 * np.pi, a + 2.0 * np.pi, a)   # sharp left turns: last
        # smallest angle, then the furthest (angles equal within 1e-12 as in the physics walk)
        best = np.min(a)
        tie = q[a <= best + 1e-12]
        nxt = int(tie[np.argmax(d2[tie])])
        used[nxt] = True
        links.append(nxt)
        dx, dy = xs[nxt] - xs[p], ys[nxt] - ys[p]
        p = nxt
        if top[nxt]:
            return np.asarray(links, dtype=np.int64), True
    return np.asarray(links, dtype=np.int64), False


def side_chain(x, bottom, top, side, r_m, from_top=False):
    """The chain of ``side`` over positions ``x`` [n, 2] (indices, bottom -> top) and the indices
    of the grains it had to leave out.

    The walk (``_walk``) starts from the outermost bottom-platen grain that has a grain outside
    the platen within ``r_m`` (an outermost platen grain may have none: the walk would stop at
    once). A walk that still stops before the top platen ends in a dead end; that grain is left
    out and the walk repeated (up to ``MAX_SKIPS`` times). ``from_top``: the walk of the mirror
    image y -> -y from the top platen, reversed."""
    sign = 1.0 if side == "right" else -1.0
    xs = np.ascontiguousarray(sign * x[:, 0])
    ys = np.ascontiguousarray(-x[:, 1] if from_top else x[:, 1])
    low, high = (top, bottom) if from_top else (bottom, top)
    skip = np.zeros(len(xs), dtype=np.bool_)
    inner = np.nonzero(~low)[0]
    for _ in range(MAX_SKIPS):
        cand = np.nonzero(low & ~skip)[0]
        if len(cand) and len(inner):
            near = np.hypot(xs[cand, None] - xs[None, inner], ys[cand, None] - ys[None, inner]).min(axis=1)
            cand = cand[near <= r_m]
        if not len(cand):
            break
        start = cand[np.lexsort((ys[cand], xs[cand]))[-1]]
        links, reached = _walk(xs, ys, int(start), low | skip, high, float(r_m))
        if reached:
            return (links[::-1] if from_top else links), np.nonzero(skip)[0]
        skip[links[-1]] = True
    raise ValueError(f"the {side} membrane found no chain from platen to platen within r_m = {r_m:g} m "
                     f"(after leaving out {int(skip.sum())} grains): a gap in the side wider than r_m")


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
        self.built_at = -1
        self._selection = None
        self.positions = {}
        self.forces = {}
        self.total = {}
        self._order_checked = None

    # -- chains ------------------------------------------------------------------------------

    def rebuild(self, sim):
        """Rebuild both chains from the positions of every grain (collective), from the bottom on
        even rebuilds and from the top on odd ones."""
        e, n = sim.elements, sim.elements.n_owned
        parts = sim.comm.allgather((e.gid[:n].copy(), e.x[:n, :2].copy()))
        gid = np.concatenate([p[0] for p in parts])
        x = np.concatenate([p[1] for p in parts])
        o = np.argsort(gid, kind="stable")
        gid, x = gid[o], x[o]
        bottom, top = np.isin(gid, self.bottom), np.isin(gid, self.top)
        from_top = self.rebuilds % 2 == 1
        chains = {}
        self.skipped = {}
        for side in SIDES:
            links, skipped = side_chain(x, bottom, top, side, self.r_m, from_top)
            chains[side] = gid[links]
            self.skipped[side] = gid[skipped]
        self.set_chains(chains)
        self.rebuilds += 1
        self.built_at = sim.step_count

    def set_chains(self, chains):
        self.chains = {s: np.asarray(chains[s], dtype=np.int64) for s in SIDES}
        self._selection = ElementSelection(np.concatenate([self.chains[s] for s in SIDES]), "membrane gids")

    def gather_positions(self, sim):
        """{side: [m, 2]} positions of the chains' grains (collective, the same on every rank)."""
        e = sim.elements
        rows, idx = self._selection.rows(e, sim.comm)
        parts = sim.comm.allgather((idx, e.x[rows, :2].copy()))
        total = len(self._selection.gids)
        x = np.empty((total, 2))
        for i, p in parts:
            x[i] = p
        m = len(self.chains[SIDES[0]])
        return {SIDES[0]: x[:m], SIDES[1]: x[m:]}

    # -- the fix -----------------------------------------------------------------------------

    def post_force(self, sim):
        key = tuple(map(id, sim.fixes))
        if self._order_checked != key:
            _check_order(sim, self)
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
        return np.vstack([self.positions["right"], self.positions["left"][::-1]])

    def area(self):
        """Area [m^2] enclosed by ``polygon`` (shoelace; the platens close it between the chains' ends)."""
        p = self.polygon()
        x, y = p[:, 0], p[:, 1]
        return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))

    def state(self):
        """JSON-friendly state for a checkpoint (with the constructor's arguments)."""
        return {"bottom": self.bottom.tolist(), "top": self.top.tolist(), "pressure": self.pressure,
                "thickness": self.thickness, "r_m": self.r_m, "rebuild_every": self.rebuild_every,
                "chains": None if self.chains is None else {s: self.chains[s].tolist() for s in SIDES},
                "rebuilds": self.rebuilds, "built_at": self.built_at}

    @classmethod
    def from_state(cls, s):
        m = cls(s["bottom"], s["top"], s["pressure"], s["thickness"], s["r_m"], s["rebuild_every"])
        if s["chains"] is not None:
            m.set_chains(s["chains"])
        m.rebuilds = int(s["rebuilds"])
        m.built_at = int(s["built_at"])
        return m


__all__ = ["MembraneLoad", "SIDES"]
