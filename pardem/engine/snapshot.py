"""One checkpoint payload and one restore for any ``Simulation``: bonded, granular, with plates,
walls or a periodic cell, on any number of ranks.

``payload(sim, attrs)`` gives what ``pardem.io.checkpoint.write_checkpoint`` stores: the owned
element rows, each bond once, each rank's contact list (with its history), and the state of the
time loop (step, clock, damping, stress, the contact sums and energies of the last step, the slab
cuts, the cell, the plates). A protocol adds its own attributes (deck, constants, protocol state).

``read(comm, path, meta, ...)`` is the way back: on the rank count (and slab axis) that wrote the
file every rank reads exactly its rows, its slab cuts and its contact list, so the continued run is
bit for bit the uninterrupted one; on another count the slabs are re-cut, the elements go to their
new owners and the contact lists are rebuilt with their histories found by gid pair. The caller
builds its ``Simulation`` from the returned parts and calls ``resume(sim, meta, same)``.
"""
import json
from dataclasses import dataclass, fields

import numpy as np

from pardem.engine.contacts import pair_keys
from pardem.engine.periodic_cell import PeriodicCell
from pardem.engine.state import PROPERTY_PREFIX, Bonds, Elements, Plates
from pardem.io import checkpoint
from pardem.io.checkpoint import BOND_DATASETS, CONTACT_DATASETS, ELEMENT_DATASETS
from pardem.parallel.slabs import Slabs


def payload(sim, attrs=None):
    """``(groups, attrs)`` of the current state of ``sim`` (every rank, collective), with the
    caller's ``attrs`` (deck, constants, protocol state: JSON-able) merged in."""
    e, b, c = sim.elements, sim.bonds, sim.contacts
    n = e.n_owned
    elements = {k: getattr(e, k)[:n] for k in ELEMENT_DATASETS if k != "x_build"}
    # the positions of the last neighbour rebuild: the next rebuild happens at the same step
    if sim.domain is not None:
        elements["x_build"] = sim.domain.x_build
    elif c is not None:
        elements["x_build"] = c.reference_positions()[:n]
    else:
        elements["x_build"] = e.x[:n]
    if e.wall_h.shape[1]:
        elements["wall_h"] = e.wall_h[:n]
    # custom per-particle arrays (``sim.particles.add_property``), under their pack names
    elements.update({PROPERTY_PREFIX + k: a[:n] for k, a in e.properties.items()})
    if b is None:
        b = Bonds.empty()
    once = b.counted_once(n)
    groups = {"elements": elements, "bonds": {k: getattr(b, k)[once] for k in BOND_DATASETS}}
    if c is not None:
        groups["contacts"] = {"gid_i": e.gid[c.i], "gid_j": e.gid[c.j], "shifts": c.shifts,
                              "history": c.history}
    slabs = sim.domain.slabs if sim.domain is not None else None
    p = sim.plates
    state = {"step": sim.step_count, "time": sim.time, "rng_state": {"generator": None},
             "slab_cut_s": slabs.cut_s if slabs is not None else np.zeros(0),
             "slab_cut_g": slabs.cut_g if slabs is not None else np.zeros(0, dtype=np.int64),
             # the compression test's plates (API walls are stored by ``system_attrs``)
             "plate_positions": p.positions.copy() if isinstance(p, Plates) else np.zeros(0),
             "plate_velocities": p.velocities(sim.time) if isinstance(p, Plates) else np.zeros(0),
             # a bond broke in the last step: the contact list is rebuilt at the next one
             "pairs_freed": int(sim.comm.any(sim.pairs_freed)),
             "run_state": run_state(sim)}
    if sim.cell is not None:
        state["cell"] = sim.cell.state()
    return groups, {**state, **(attrs or {})}


def run_state(sim):
    """What a bit-for-bit restart needs beyond the arrays (same on every rank, collective): the
    step's clock (an adaptive step changes it), the global damping, the last step's stress, and
    each rank's contact sums, contact energy and lost-cement count (read between steps)."""
    c = sim.contacts
    mine = {"sums": [float(v) for v in c.sums] if c is not None else [],
            "energy": float(sim.contact_energy), "lost": int(c.lost) if c is not None else 0,
            "exact": c.exact_state() if c is not None else None}
    return {"dt": float(sim.dt), "clock": [int(sim._clock[0]), float(sim._clock[1])],
            "time": float(sim.time), "viscous_damping": float(sim.viscous_damping),
            "stress": np.asarray(sim.stress, dtype=float).tolist(), "per_rank": sim.comm.allgather(mine)}


def _decoded(value):
    return json.loads(value) if isinstance(value, (str, bytes)) else value


def cell_of(meta):
    """The ``PeriodicCell`` stored in checkpoint attributes ``meta``, or None."""
    state = meta.get("cell")
    return None if state is None else PeriodicCell.from_state(_decoded(state))


@dataclass
class Parts:
    """The state read back on this rank: build the ``Simulation`` from it, then ``resume``."""
    elements: Elements
    bonds: Bonds
    contacts: object          # the caller's Contacts with the stored list, or None
    domain: object            # the slab layer (SlabComm) or None on one process
    same: bool                # same rank count and slab axis as the writer: bit for bit


def read(comm, path, meta, slab_axis, contacts=None, slab_comm=None, bond_options=None):
    """Read checkpoint ``path`` (attributes ``meta`` from ``checkpoint.inspect``) onto ``comm``.

    slab_axis : the axis of the slabs (another than the stored one re-cuts them);
    contacts : an empty ``Contacts`` of the run's law (or None for runs without contacts);
    slab_comm : ``slab_comm(slabs) -> SlabComm`` (called when ``comm.size > 1``);
    bond_options : keyword arguments of ``Bonds.unpack`` (damped, breakable, densify_p0).
    Collective; a stored contact whose element is missing fails on every rank (ValueError).
    """
    same = int(meta["n_ranks"]) == comm.size and int(slab_axis) == int(meta["slab_axis"])
    names = list(ELEMENT_DATASETS) + (["wall_h"] if checkpoint.has_dataset(path, "elements/wall_h") else [])
    names += checkpoint.property_datasets(path)    # custom per-particle arrays: Elements.unpack takes them
    if same:
        counts = np.asarray(meta["owned_counts"], dtype=np.int64)
        off = int(counts[:comm.rank].sum())
        el = checkpoint.read_rows(path, "elements", names, slice(off, off + int(counts[comm.rank])))
        slabs = Slabs(slab_axis, meta["slab_cut_s"], meta["slab_cut_g"]) if comm.size > 1 else None
    else:
        N = int(meta["n_elements"])
        slabs = None
        if comm.size > 1:
            stripe = slice(comm.rank * N // comm.size, (comm.rank + 1) * N // comm.size)
            chunk = checkpoint.read_rows(path, "elements", ["x", "gid"], stripe)
            slabs = Slabs.balanced(comm, slab_axis, chunk["x"][:, slab_axis], chunk["gid"])
            el = checkpoint.read_rows(path, "elements", names, (["x", "gid"], lambda d: slabs.owner(
                d["x"][:, slab_axis], d["gid"]) == comm.rank))
        else:
            el = checkpoint.read_rows(path, "elements", names, slice(0, N))
    mine = el["gid"]
    if int(meta["n_bonds"]):
        bd = checkpoint.read_rows(path, "bonds", checkpoint.bond_datasets(path), (["gid_i", "gid_j"],
                                  lambda d: np.isin(d["gid_i"], mine) | np.isin(d["gid_j"], mine)))
        bonds = Bonds.unpack([bd], copy=False, **(bond_options or {"damped": False}))
    else:
        bonds = Bonds.empty()
    el["inv_mass"] = 1.0 / el["mass"]
    el["inv_inertia"] = 1.0 / el["inertia"]
    elements = Elements.unpack([el], len(mine), copy=False)
    cl = None
    if contacts is not None:
        cl = checkpoint.read_rows(path, "contacts", list(CONTACT_DATASETS), slice(0, None))
    domain = slab_comm(slabs) if comm.size > 1 else None
    cell = contacts.cell if contacts is not None else None
    if same:
        if domain is None:
            bonds.relink(elements.gid)
            if contacts is not None:
                _take_list(comm, contacts, elements, cl, x_build=el["x_build"])
        else:
            elements, bonds = domain.borders(elements, bonds, extra=contacts.skin if contacts is not None else 0.0)
            domain.x_build = el["x_build"].copy()    # the same rebuild steps as the uninterrupted run
            if contacts is not None:
                _take_list(comm, contacts, elements, _block(meta, cl, comm.rank))
    else:
        table = _history_table(cl) if contacts is not None else None
        if domain is None:
            bonds.relink(elements.gid)
            if cell is not None:
                cell.wrap(elements)
        elif contacts is None:
            elements, bonds = domain.setup(elements, bonds)
        else:
            elements, bonds, table = domain.setup_with_pairs(elements, bonds, table)
        if contacts is not None:
            contacts.rebuild(elements, bonds, table)
    # the forces of the stored state, by gid (migration may have reordered the rows)
    srt = np.argsort(el["gid"])
    order = srt[np.searchsorted(el["gid"][srt], elements.gid[:elements.n_owned])]
    elements.f[:elements.n_owned] = el["f"][order]
    elements.t[:elements.n_owned] = el["t"][order]
    return Parts(elements, bonds, contacts, domain, same)


def resume(sim, meta, same):
    """Put back the time loop's state of ``meta`` into the freshly built ``sim``: step, clock,
    damping, stress, pairs freed, and (same ranks) each rank's contact sums and energy (on another
    rank count rank 0 takes the global sums)."""
    sim.step_count = int(meta["step"])
    sim.time = sim.step_count * sim.dt
    sim.pairs_freed = bool(int(meta.get("pairs_freed", 0)))
    rs = meta.get("run_state")
    if rs is None:
        return
    rs = _decoded(rs)
    sim.dt = float(rs["dt"])
    sim._clock = (int(rs["clock"][0]), float(rs["clock"][1]))
    sim.time = float(rs["time"])
    sim.viscous_damping = float(rs["viscous_damping"])
    sim.stress = np.asarray(rs["stress"], dtype=np.float64).reshape(3, 3)
    per = rs["per_rank"]
    c = sim.contacts
    if same:
        mine = per[sim.comm.rank]
        sim.contact_energy = float(mine["energy"])
        if c is not None:
            c.sums[:] = mine["sums"]
            c.lost = int(mine["lost"])
    elif sim.comm.is_root:
        sim.contact_energy = float(sum(q["energy"] for q in per))
        if c is not None:
            c.sums[:] = np.sum([q["sums"] for q in per], axis=0)
            c.lost = int(sum(q["lost"] for q in per))
    if c is not None:   # the exact sums of reproducible contacts (the uninterrupted run's stress)
        c.restore_exact_state([q.get("exact") for q in per], sim.comm.rank, same)


def _block(meta, cl, rank):
    """This rank's block of the stored contact lists."""
    counts = np.asarray(meta["contacts_counts"], dtype=np.int64)
    off = int(counts[:rank].sum())
    return {k: v[off:off + int(counts[rank])] for k, v in cl.items()}


def _history_table(cl):
    """The stored pairs with a history (each once), for a list rebuilt on other rows."""
    live = np.any(cl["history"] != 0.0, axis=1)
    _, first = np.unique(pair_keys(cl["gid_i"][live], cl["gid_j"][live]), return_index=True)
    return {k: cl[k][live][first] for k in ("gid_i", "gid_j", "history")}


def _take_list(comm, contacts, elements, cl, x_build=None):
    """Take back a stored list on the same rows (bit-for-bit restart); fails on every rank."""
    err = None
    try:
        contacts.restore(elements, cl["gid_i"], cl["gid_j"], cl["shifts"], cl["history"], x_build=x_build)
    except ValueError as exc:
        err = exc
    if comm.any(err is not None):    # every rank stops, none is left waiting
        raise err or ValueError("a stored contact's element is missing on another rank")


# -- any system built with the Python API (pardem.engine.builders), walls included ---------------

def _init_fields(params):
    """The constructor arguments of a parameter dataclass (derived fields left out), JSON-able."""
    return {f.name: getattr(params, f.name) for f in fields(params) if f.init}


def wall_attrs(walls):
    """The API walls (``pardem.engine.walls.Walls``) as JSON-able attributes, or None."""
    if walls is None:
        return None
    return {"normals": walls.normals.tolist(), "offsets0": walls.offsets0.tolist(),
            "velocities": walls.velocities.tolist(), "time0": walls.time0, "law": _init_fields(walls.law)}


def walls_of(attrs):
    """The ``Walls`` of ``wall_attrs`` (exactly the stored planes), or None; call ``move_to(sim.time)``
    once the run's clock is restored."""
    if attrs is None:
        return None
    from pardem.engine.walls import Walls
    from pardem.physics import walls as wall_kernels
    normals = np.asarray(attrs["normals"])
    walls = Walls(normals, normals * np.asarray(attrs["offsets0"])[:, None], wall_kernels.Params(**attrs["law"]),
                  attrs["velocities"], time0=attrs["time0"])
    walls.normals = np.ascontiguousarray(normals, dtype=np.float64)
    walls.offsets0 = np.asarray(attrs["offsets0"], dtype=np.float64)
    return walls


def system_attrs(sim):
    """What ``load`` needs to rebuild ``sim``'s parts besides the arrays (JSON-able, every rank)."""
    from pardem.engine.walls import Walls
    from pardem.physics.contact_laws import LAWS
    c, p, d = sim.contacts, sim.plates, sim.domain
    if p is not None and not isinstance(p, Walls):
        raise ValueError("snapshot.write saves systems built with the Python API (walls from add_walls); "
                         "a compression test's plates are saved by its protocol (pardem.protocols.compression)")
    law = None
    if c is not None:
        law = next(name for name, row in LAWS.items() if c.law is row)
    from pardem.engine.plane import plane_of
    plane = plane_of(sim)
    switches = (sim.bonds if sim.bonds is not None else Bonds.empty()).flags()
    # the switches are the same on every rank (builders give a rank without bonds the material's);
    # a builder that broke this would save a checkpoint that restores the wrong physics
    every = sim.comm.allgather(switches)
    if any(s != switches for s in every):
        raise ValueError(f"snapshot.write: the ranks disagree on the bond switches {every}; "
                         "every rank's Bonds must carry the material's damped/breakable/densify_p0")
    return {"kind": "system", "dt": sim.dt,
            # the 2D mode (pardem.engine.plane): its plane constraint is part of the system
            "dimension": 2 if plane is not None else 3, "plane_z0": plane.z0 if plane is not None else 0.0, "max_speed": float(np.sqrt(sim.max_speed2)),
            "check_every": sim.check_every, "viscous_damping": sim.viscous_damping,
            "slab_axis": d.slabs.axis if d is not None else 0,
            "bonds": switches,
            "contacts": None if c is None else {"law": law, "params": _init_fields(c.params), "skin": c.skin,
                                                "reach": c.cut},
            "walls": wall_attrs(p),
            "slab": None if d is None else {"ghost_range": d.ghost_range, "skin": d.skin,
                                            "balance_every": d.balance_every, "threshold": d.threshold,
                                            "balance_by": d.balance_by}}


def write(sim, path, attrs=None, mode="auto"):
    """Checkpoint ``sim`` (built with ``pardem.bonded_system`` / ``granular_system``, walls included)
    to ``path`` (collective). Fixes and operations are Python objects of the script: add them again
    after ``load`` (as a LAMMPS restart re-reads its fixes from the input script); the 2D mode's
    plane constraint (``pardem.engine.plane``) is part of the system and comes back by itself."""
    system = system_attrs(sim)
    groups, state = payload(sim, {"deck": {"kind": "system"}, "constants": system,
                                  "slab_axis": system["slab_axis"], **(attrs or {})})
    checkpoint.write_checkpoint(path, sim.comm, groups, {}, state, mode=mode)


def load(comm, path, slab_axis=None):
    """The ``Simulation`` of a checkpoint written by ``write``, on ``comm`` (any number of ranks;
    bit for bit on the rank count that wrote it). ``slab_axis`` re-cuts the slabs along another axis."""
    from pardem.engine.contacts import Contacts
    from pardem.engine.simulation import Simulation
    from pardem.parallel.slab_comm import SlabComm
    from pardem.physics.contact_laws import LAWS, law_params
    meta = checkpoint.inspect(path, comm=comm)     # collective: every byte verified
    s = meta["constants"]
    if not isinstance(s, dict) or s.get("kind") != "system":
        raise checkpoint.CheckpointError(f"{path}: not a checkpoint of snapshot.write (a protocol's checkpoint: "
                                         f"continue it with its driver's --restart)")
    cell = cell_of(meta)
    ct = s["contacts"]
    contacts = None if ct is None else Contacts(LAWS[ct["law"]], law_params(ct["law"], ct["params"]), ct["skin"],
                                                cell, reach=ct["reach"])
    sl = s["slab"] or {"ghost_range": ct["reach"] if ct else 0.0, "skin": ct["skin"] if ct else 0.0,
                       "balance_every": 0, "threshold": 0.05, "balance_by": "count"}
    axis = int(s["slab_axis"] if slab_axis is None else slab_axis)
    parts = read(comm, path, meta, axis, contacts=contacts, bond_options=s["bonds"],
                 slab_comm=lambda slabs: SlabComm(comm, slabs, sl["ghost_range"], sl["skin"],
                                                  balance_every=sl["balance_every"], threshold=sl["threshold"],
                                                  balance_by=sl["balance_by"], cell=cell))
    walls = walls_of(s["walls"])
    sim = Simulation(comm, parts.elements, parts.bonds, walls, s["dt"], max_speed=s["max_speed"],
                     check_every=s["check_every"], domain=parts.domain, contacts=contacts, cell=cell,
                     viscous_damping=s["viscous_damping"])
    if int(s.get("dimension", 3)) == 2:
        from pardem.engine.plane import PlaneConstraint
        sim.fixes.append(PlaneConstraint(s.get("plane_z0", 0.0)))
    resume(sim, meta, parts.same)
    if walls is not None:
        walls.move_to(sim.time)
    return sim
