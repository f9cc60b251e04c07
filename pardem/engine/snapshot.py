"""One checkpoint payload and one restore for any ``Simulation``: bonded, granular, with plates,
walls or a periodic cell, on any number of ranks.

``payload(sim, attrs)`` gives what ``pardem.io.checkpoint.write_checkpoint`` stores: the owned
element rows, each bond once, each rank's contact list (with its history), and the state of the
time loop (step, clock, damping, stress, the contact sums and energies of the last step, the slab
cuts, the cell, the plates). A protocol adds its own attributes (deck, constants, protocol state).

``pardem.restart.read`` is the way back (it reads the file; the engine opens none): the caller
builds its ``Simulation`` from the returned ``Parts`` and calls ``resume(sim, meta, same)``.
"""
import json
from dataclasses import dataclass

import numpy as np

from pardem.engine.state import PROPERTY_PREFIX, Bonds, Elements, Plates
from pardem.io.checkpoint import BOND_DATASETS, ELEMENT_DATASETS


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


@dataclass
class Parts:
    """The state read back on this rank (``pardem.restart.read``): build the ``Simulation`` from it,
    then ``resume``."""
    elements: Elements
    bonds: Bonds
    contacts: object          # the caller's Contacts with the stored list, or None
    domain: object            # the slab layer (SlabComm) or None on one process
    same: bool                # same rank count and slab axis as the writer: bit for bit


def resume(sim, meta, same):
    """Put back the time loop's state of ``meta`` into the freshly built ``sim``: step, clock,
    damping, stress, pairs freed, and (same ranks) each rank's contact sums and energy (on another
    rank count rank 0 takes the global sums)."""
    sim.step_count = int(meta["step"])
    sim.time = sim.step_count * sim.dt
    sim.forces_restored = True      # the stored forces include the saved run's fixes (fixes.add)
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
