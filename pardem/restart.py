"""Save and restore any system: the one checkpoint payload and the one restore.

``save(sim, path)`` writes a checkpoint of a ``Simulation`` built by ``pardem.engine.system.build``
(collective); ``load(comm, path)`` makes the ``Simulation`` back on any number of ranks, bit for bit
on the rank count (and slab axis) that wrote it. The file holds the state arrays
(``pardem.engine.snapshot.payload``) and the system's description (``pardem.engine.system.describe``:
contact model, bond switches, walls, cell, integration, decomposition), which the restore reads.
Protocols add their own attributes (deck, protocol state, series) through ``payload``.

On another rank count the slabs are re-cut, the elements go to their new owners and the contact
lists are rebuilt with their histories found by gid pair. This module sits above the engine and
the I/O layer: the engine opens no file.
"""
import numpy as np

from pardem.engine import snapshot
from pardem.engine.contacts import Contacts, pair_keys
from pardem.engine.granular import GranularCase
from pardem.engine.periodic_cell import PeriodicCell
from pardem.engine.snapshot import Parts
from pardem.engine.state import Bonds, Elements
from pardem.engine.system import System, describe
from pardem.engine.system import restore as restore_system
from pardem.io import checkpoint
from pardem.io.checkpoint import CONTACT_DATASETS, ELEMENT_DATASETS, CheckpointError
from pardem.parallel.slab_comm import SlabComm
from pardem.parallel.slabs import Slabs
from pardem.physics.contact_laws import LAWS, law_params

KIND = "system"


def constants(sim, extras=None):
    """The checkpoint's ``constants`` of ``sim``: its description and the facts the restore needs
    (density, contact reach, ghost range, bond switches), plus the caller's JSON-able ``extras``
    (a protocol's facts about its case). Collective (the ranks' bond switches are compared)."""
    switches = (sim.bonds if sim.bonds is not None else Bonds.empty()).flags()
    # the switches are the same on every rank (the builder gives a rank without bonds the
    # material's); a builder that broke this would save a checkpoint restoring the wrong physics
    every = sim.comm.allgather(switches)
    if any(s != switches for s in every):
        raise ValueError(f"save: the ranks disagree on the bond switches {every}; every rank's Bonds "
                         "must carry the material's damped/breakable/densify_p0")
    return {"kind": KIND, "system": describe(sim).to_dict(), "density": sim.density, "reach": sim.reach,
            "ghost_range": sim.ghost_range, "dt_critical": sim.dt_critical, "bond_switches": switches,
            "case": dict(extras or {})}


def slab_axis_of(sim):
    """The slab axis of ``sim`` (the builder's choice on one process)."""
    return int(sim.domain.slabs.axis) if sim.domain is not None else int(sim.system.decomposition.slab_axis)


def payload(sim, attrs=None, extras=None):
    """``(groups, series, attrs)`` for ``pardem.io.checkpoint.write_checkpoint`` (every rank): the
    state of ``sim``, its ``constants`` (with ``extras``) and the caller's ``attrs`` (deck,
    protocol state: JSON-able)."""
    groups, state = snapshot.payload(sim, {"deck": {"kind": KIND}, "constants": constants(sim, extras),
                                           "slab_axis": slab_axis_of(sim), **(attrs or {})})
    return groups, {}, state


def save(sim, path, attrs=None, mode="auto", extras=None):
    """Checkpoint ``sim`` (built by ``pardem.engine.system.build``, walls included) to ``path``
    (collective; atomic: ``pardem.io.checkpoint``); ``extras``: a protocol's JSON-able facts about
    the case (``GranularCase.extras``, given back by ``load_case``). Fixes and operations are the script's Python
    objects: add them again after ``load`` (as a LAMMPS restart re-reads its fixes from the input
    script); the 2D mode's plane constraint is part of the system and comes back by itself."""
    groups, series, state = payload(sim, attrs, extras)
    checkpoint.write_checkpoint(path, sim.comm, groups, series, state, mode=mode)


def load(comm, path, slab_axis=None, meta=None):
    """The ``Simulation`` of checkpoint ``path`` (written by ``save`` or by a protocol through
    ``payload``) on ``comm``: any number of ranks, bit for bit on the rank count and slab axis that
    wrote it. ``slab_axis`` re-cuts the slabs along another axis; ``meta`` the file's attributes when
    already inspected (``pardem.io.checkpoint.inspect``, collective: every byte verified)."""
    meta = checkpoint.inspect(path, comm=comm) if meta is None else meta
    c = meta["constants"]
    if not isinstance(c, dict) or c.get("kind") != KIND:
        raise CheckpointError(f"{path}: not a checkpoint of a pardem System (a compression test's checkpoint: "
                              f"continue it with its driver's --restart)")
    system = System.from_dict(c["system"])
    cell = None if system.cell is None else PeriodicCell.from_state(system.cell.state)
    dec = system.decomposition
    if slab_axis is not None:
        allowed = (0, 1) if system.dimension == 2 else (0, 1, 2)
        if isinstance(slab_axis, bool) or slab_axis not in allowed:
            raise ValueError(f"slab_axis = {slab_axis!r}: expected one of {allowed}"
                             + (" for a 2D checkpoint (the grains lie in the plane z = 0)" if system.dimension == 2
                                else ""))
    axis = int(dec.slab_axis if slab_axis is None else slab_axis)
    contacts = None
    if system.contacts is not None:
        ct = system.contacts
        contacts = Contacts(LAWS[ct.law], law_params(ct.law, ct.params), dec.skin, cell, reach=c["reach"])
    parts = read(comm, path, meta, axis, contacts=contacts, bond_options=c["bond_switches"],
                 slab_comm=lambda slabs: SlabComm(comm, slabs, c["ghost_range"], dec.skin,
                                                  balance_every=dec.balance_every, threshold=dec.balance_threshold,
                                                  balance_by=dec.balance_by, cell=cell))
    sim = restore_system(comm, system, parts, cell, c["density"])
    sim.reach, sim.ghost_range, sim.dt_critical = c["reach"], c["ghost_range"], c["dt_critical"]
    sim.n_elements = int(meta["n_elements"])
    if parts.domain is None:
        sim.system.decomposition.slab_axis = axis
    snapshot.resume(sim, meta, parts.same)
    if sim.plates is not None:
        sim.plates.move_to(sim.time)
    return sim


def load_case(comm, path, slab_axis=None, meta=None):
    """The ``GranularCase`` of checkpoint ``path``: the ``Simulation`` of ``load`` and the extras
    stored with it (``save(..., extras=)``, ``payload(..., extras=)``)."""
    meta = checkpoint.inspect(path, comm=comm) if meta is None else meta
    sim = load(comm, path, slab_axis=slab_axis, meta=meta)
    return GranularCase(sim, dict(meta["constants"].get("case") or {}))


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
