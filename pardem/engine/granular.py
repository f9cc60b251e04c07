"""Granular cases: spheres interacting by contact in a periodic cell, on any number of ranks.

Composes the pieces (no physics here): ``Elements`` from given centres and radii, the
``PeriodicCell``, ``Contacts`` with one law, the slab layer when there are several ranks (periodic
slab axis allowed), and a ``Simulation``; plus the checkpoint payload and the restart of such a
case. Used by the GRAN benchmark, the granular tests and the granular drivers.

Between steps a driver may switch the contact parameters (``set_contact_params``: e.g. friction
after a frictionless preparation, or cemented Hertz-Mindlin contacts, whose history is wider) and
the global damping (``set_viscous_damping``); both update the restart constants, so a checkpoint
written afterwards restarts with them. Cementation itself is ``pardem.engine.cement``.

The contact history lives in the checkpoint as each rank's list (see ``pardem.io.checkpoint``), so
a restart on the same number of ranks continues bit for bit; on another number of ranks the lists
are rebuilt and the histories found again by their gid pairs.
"""
from dataclasses import dataclass, field

import numpy as np

from pardem.engine.contacts import Contacts, pair_keys
from pardem.io import checkpoint
from pardem.io.checkpoint import CONTACT_DATASETS, ELEMENT_DATASETS
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import Slabs
from pardem.engine.periodic_cell import PeriodicCell
from pardem.physics.contact_laws import LAWS, critical_time_step, law_params
from pardem.engine.simulation import Simulation
from pardem.engine.state import Bonds, Elements


def simple_cubic(n, radius, spacing=1.998, jitter=0.0002, seed=12345):
    """Centres [n^3, 3] of a simple cubic lattice of spacing ``spacing * radius`` jittered by
    ``+-jitter * radius`` per axis (uniform, seeded), and the periodic box edge [m]."""
    rng = np.random.default_rng(seed)
    a = spacing * radius
    g = np.arange(n) * a + 0.5 * a
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    pos += rng.uniform(-jitter * radius, jitter * radius, size=pos.shape)
    return pos, n * a


@dataclass
class GranularCase:
    """A granular simulation on this rank and the constants needed to restart it."""
    sim: Simulation
    constants: dict = field(default_factory=dict)


def set_contact_params(case, params):
    """Switch every rank's contact parameters (dict, same law) between steps, e.g. friction after a
    frictionless preparation or the cement springs before ``pardem.engine.cement.cement_contacts``; the
    history is widened as the law needs, and the restart constants follow."""
    c = case.constants
    prm = law_params(c["law"], params)
    sim = case.sim
    radii = sim.elements.radius[:sim.elements.n_owned]
    r_min = float(sim.comm.min(float(radii.min()) if len(radii) else np.inf))
    dt_c = critical_time_step(c["law"], prm, np.array([r_min]), c["density"])
    if not sim.dt <= dt_c:
        raise ValueError(f"dt = {sim.dt:.6g} s is above the critical step {dt_c:.6g} s of the new "
                         "contact parameters")
    sim.contacts.set_params(prm)
    c["params"] = dict(params)
    c["dt_critical"] = dt_c


def set_viscous_damping(case, rate):
    """Change the global viscous damping C [1/s] between steps (the restart constants follow)."""
    case.sim.viscous_damping = float(rate)
    case.constants["viscous_damping"] = float(rate)


def build(comm, positions, radii, density, law, params, box_lo, box_length, dt, skin,
          periodic=(True, True, True), rate=(0.0, 0.0, 0.0), servo=None, viscous_damping=0.0,
          velocities=None, angular_velocities=None, slab_axis=0, balance_every=0):
    """A granular case from global centres [n, 3] and radii [n] (every rank passes the same).

    density [kg/m^3]; law, params: the contact law and its parameters (dict); box_lo [3],
    box_length [3] [m]: the periodic cell; dt [s]; skin [m]; rate [3] [1/s], servo
    ``(p0, gain, max_rate)``: the cell's deformation; velocities [n, 3] [m/s] optional.
    Rank r keeps its slab's elements (slabs along ``slab_axis``, balanced counts).
    """
    pos = np.asarray(positions, dtype=np.float64)
    per = np.asarray(periodic, dtype=bool)
    lo0, edge = np.asarray(box_lo, dtype=np.float64), np.asarray(box_length, dtype=np.float64)
    pos = np.where(per, lo0 + np.mod(pos - lo0, edge), pos)   # slabs are cut in the cell's frame
    n = len(pos)
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (n,))
    prm = law_params(law, params)
    dt_c = critical_time_step(law, prm, radii, density)
    if not 0.0 < dt <= dt_c:
        raise ValueError(f"dt = {dt:.6g} s: expected a value in (0, {dt_c:.6g}] s, the critical time "
                         f"step of the {law} contacts of these spheres (take 0.1-0.3 of it)")
    gids = np.arange(n, dtype=np.int64)
    cell = PeriodicCell(box_lo, box_length, periodic, rate, servo)
    reach = 2.0 * float(radii.max()) + float(skin)
    constants = {"density": float(density), "law": law, "params": dict(params), "dt": float(dt),
                 "skin": float(skin), "reach": reach, "slab_axis": int(slab_axis),
                 "viscous_damping": float(viscous_damping), "n_elements": n,
                 "balance_every": int(balance_every), "dt_critical": dt_c}
    contacts = Contacts(LAWS[law], prm, skin, cell, reach=reach)
    domain = None
    if comm.size > 1:
        stripe = slice(comm.rank, None, comm.size)
        slabs = Slabs.balanced(comm, slab_axis, pos[stripe, slab_axis], gids[stripe])
        owned = slabs.owner(pos[:, slab_axis], gids) == comm.rank
    else:
        owned = np.ones(n, dtype=bool)
    e = Elements.from_spheres(pos[owned], radii[owned], density, gids[owned])
    if velocities is not None:
        e.v[:] = np.asarray(velocities)[owned]
    if angular_velocities is not None:
        e.w[:] = np.asarray(angular_velocities)[owned]
    bonds = Bonds.empty()
    if comm.size > 1:
        domain = SlabComm(comm, slabs, reach, skin, balance_every=balance_every, cell=cell)
        e, bonds, table = domain.setup_with_pairs(e, bonds, contacts.table())
        contacts.rebuild(e, bonds, table)
    else:
        cell.wrap(e)
        contacts.rebuild(e, bonds)
    sim = Simulation(comm, e, bonds, None, dt, domain=domain, contacts=contacts, cell=cell,
                     viscous_damping=viscous_damping)
    return GranularCase(sim=sim, constants=constants)


def checkpoint_payload(case):
    """(groups, series, attrs) for ``checkpoint.write_checkpoint`` (every rank)."""
    sim = case.sim
    e, c = sim.elements, sim.contacts
    n = e.n_owned
    elements = {k: getattr(e, k)[:n] for k in ELEMENT_DATASETS if k != "x_build"}
    x_build = sim.domain.x_build if sim.domain is not None else c.reference_positions()[:n]
    elements["x_build"] = x_build
    bonds = Bonds.empty()
    contacts = {"gid_i": e.gid[c.i], "gid_j": e.gid[c.j], "shifts": c.shifts, "history": c.history}
    slabs = sim.domain.slabs if sim.domain is not None else None
    attrs = {"step": sim.step_count, "time": sim.time, "deck": {"kind": "granular"},
             "constants": case.constants, "cell": sim.cell.state(),
             "rng_state": {"generator": None}, "plate_positions": np.zeros(0),
             "plate_velocities": np.zeros(0), "slab_axis": case.constants["slab_axis"],
             "slab_cut_s": slabs.cut_s if slabs is not None else np.zeros(0),
             "slab_cut_g": slabs.cut_g if slabs is not None else np.zeros(0, dtype=np.int64),
             "run_state": run_state(sim)}
    return {"elements": elements, "bonds": {k: getattr(bonds, k) for k in checkpoint.BOND_DATASETS},
            "contacts": contacts}, {}, attrs


def run_state(sim):
    """What a bit-for-bit restart needs beyond the arrays and constants (same on every rank):
    the current step and its clock (an adaptive step changes them), the current global damping,
    the last step's stress, and each rank's contact sums, contact energy and lost-cement count
    (read between steps by the protocols' checks). Collective."""
    c = sim.contacts
    per_rank = sim.comm.allgather({"sums": [float(v) for v in c.sums], "energy": float(sim.contact_energy),
                                   "lost": int(c.lost)})
    return {"dt": float(sim.dt), "clock": [int(sim._clock[0]), float(sim._clock[1])],
            "time": float(sim.time), "viscous_damping": float(sim.viscous_damping),
            "stress": np.asarray(sim.stress, dtype=float).tolist(), "per_rank": per_rank}


def _restore_run_state(sim, rs, same):
    """Put back ``run_state`` (on another rank count, rank 0 takes the global sums)."""
    sim.dt = float(rs["dt"])
    sim._clock = (int(rs["clock"][0]), float(rs["clock"][1]))
    sim.time = float(rs["time"])
    sim.viscous_damping = float(rs["viscous_damping"])
    sim.stress = np.asarray(rs["stress"], dtype=np.float64).reshape(3, 3)
    per = rs["per_rank"]
    c = sim.contacts
    if same:
        mine = per[sim.comm.rank]
        c.sums[:] = mine["sums"]
        sim.contact_energy = float(mine["energy"])
        c.lost = int(mine["lost"])
    elif sim.comm.is_root:
        c.sums[:] = np.sum([q["sums"] for q in per], axis=0)
        sim.contact_energy = float(sum(q["energy"] for q in per))
        c.lost = int(sum(q["lost"] for q in per))


def write(case, path, mode="auto"):
    groups, series, attrs = checkpoint_payload(case)
    checkpoint.write_checkpoint(path, case.sim.comm, groups, series, attrs, mode=mode)


def restore(comm, path, slab_axis=None):
    """The granular case of checkpoint ``path`` on ``comm`` (any number of ranks; ``slab_axis``
    re-cuts the slabs along another axis). On the rank count and axis that wrote it the run
    continues bit for bit (with the ``run_state`` of checkpoints that have one)."""
    import json
    meta = checkpoint.inspect(path)
    c = meta["constants"]
    cell_state = meta["cell"]
    cell = PeriodicCell.from_state(json.loads(cell_state) if isinstance(cell_state, str) else cell_state)
    if slab_axis is not None and int(slab_axis) != int(c["slab_axis"]):
        c["slab_axis"] = int(slab_axis)
        meta["n_ranks"] = -1       # the stored slabs do not apply: re-cut as for another rank count
    axis = int(c["slab_axis"])
    same = int(meta["n_ranks"]) == comm.size
    names = list(ELEMENT_DATASETS)
    if same:
        counts = np.asarray(meta["owned_counts"], dtype=np.int64)
        off = int(counts[:comm.rank].sum())
        el = checkpoint.read_rows(path, "elements", names, slice(off, off + int(counts[comm.rank])))
        ccounts = np.asarray(meta["contacts_counts"], dtype=np.int64)
        coff = int(ccounts[:comm.rank].sum())
        cl = checkpoint.read_rows(path, "contacts", list(CONTACT_DATASETS),
                                  slice(coff, coff + int(ccounts[comm.rank])))
        slabs = Slabs(axis, meta["slab_cut_s"], meta["slab_cut_g"]) if comm.size > 1 else None
    else:
        N = int(meta["n_elements"])
        stripe = slice(comm.rank * N // comm.size, (comm.rank + 1) * N // comm.size)
        chunk = checkpoint.read_rows(path, "elements", ["x", "gid"], stripe)
        slabs = None
        if comm.size > 1:
            slabs = Slabs.balanced(comm, axis, chunk["x"][:, axis], chunk["gid"])
            el = checkpoint.read_rows(path, "elements", names, (["x", "gid"], lambda d: slabs.owner(
                d["x"][:, axis], d["gid"]) == comm.rank))
        else:
            el = checkpoint.read_rows(path, "elements", names, slice(0, N))
        cl = checkpoint.read_rows(path, "contacts", list(CONTACT_DATASETS), slice(0, None))
    el["inv_mass"] = 1.0 / el["mass"]
    el["inv_inertia"] = 1.0 / el["inertia"]
    e = Elements.unpack([el], len(el["gid"]), copy=False)
    contacts = Contacts(LAWS[c["law"]], law_params(c["law"], c["params"]), c["skin"], cell,
                        reach=c["reach"])
    bonds = Bonds.empty()
    domain = None
    if same:
        if comm.size > 1:
            domain = SlabComm(comm, slabs, c["reach"], c["skin"], balance_every=c["balance_every"],
                              cell=cell)
            e, bonds = domain.borders(e, bonds, extra=c["skin"])
            domain.x_build = el["x_build"].copy()
            err = None
            try:
                contacts.restore(e, cl["gid_i"], cl["gid_j"], cl["shifts"], cl["history"])
            except ValueError as exc:
                err = exc
            if comm.any(err is not None):    # every rank stops, none is left waiting
                raise err or ValueError("a stored contact's element is missing on another rank")
        else:
            contacts.restore(e, cl["gid_i"], cl["gid_j"], cl["shifts"], cl["history"],
                             x_build=el["x_build"])
        e.f[:e.n_owned] = el["f"]      # borders keeps the owned rows in their order
        e.t[:e.n_owned] = el["t"]
    else:
        live = np.any(cl["history"] != 0.0, axis=1)
        keys, first = np.unique(pair_keys(cl["gid_i"][live], cl["gid_j"][live]), return_index=True)
        table = {k: cl[k][live][first] for k in ("gid_i", "gid_j", "history")}
        if comm.size > 1:
            domain = SlabComm(comm, slabs, c["reach"], c["skin"], balance_every=c["balance_every"],
                              cell=cell)
            e, bonds, table = domain.setup_with_pairs(e, bonds, table)
        else:
            cell.wrap(e)
        contacts.rebuild(e, bonds, table)
        srt = np.argsort(el["gid"])     # forces of the stored state, by gid (rows were reordered)
        order = srt[np.searchsorted(el["gid"][srt], e.gid[:e.n_owned])]
        e.f[:e.n_owned] = el["f"][order]
        e.t[:e.n_owned] = el["t"][order]
    sim = Simulation(comm, e, bonds, None, c["dt"], domain=domain, contacts=contacts, cell=cell,
                     viscous_damping=c["viscous_damping"])
    sim.step_count = int(meta["step"])
    sim.time = sim.step_count * sim.dt
    rs = meta.get("run_state")
    if rs is not None:
        _restore_run_state(sim, json.loads(rs) if isinstance(rs, (str, bytes)) else rs, same)
    return GranularCase(sim=sim, constants=c)
