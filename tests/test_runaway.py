"""The stability check catches a runaway before it is written: no element may move more than
``STEP_DISPLACEMENT`` (0.1) of the smallest radius in one step (docs/physics.md, "Stability
check"), so the last checkpoint of a run that blew up is one a user can restart from.

A bonded lattice run at 3 times its critical step (``set_dt``: a script's choice the builder would
refuse) grows its speeds by orders of magnitude within tens of steps; checkpoints are written at
every step, so the last one kept is the last state that passed the check. With the former bound
alone (``max_speed`` = 1e4 m/s for 0.25 mm elements) that state was already a runaway: elements
moving several radii per step.
"""

import numpy as np
import pytest

from pardem import restart
from pardem.domains.ordered import ordered_lattice
from pardem.engine.bonding import BeamMaterial
from pardem.engine.simulation import LOADING_SPEEDS, STEP_DISPLACEMENT
from pardem.errors import InstabilityError
from pardem.io.checkpoint_writer import CheckpointWriter
from pardem.parallel.communicator import Communicator
from _util import bonded_sim

R = 0.25e-3


def _lattice(comm):
    pos, pairs, frame = ordered_lattice([8 * R] * 3, R)
    v = np.random.default_rng(1).normal(size=pos.shape) * 1e-3
    sim = bonded_sim(comm, pos, R, 1000.0, pairs, BeamMaterial(young=1e8, radius_ratio=1.0, poisson=0.3, damping=0.0),
                     frame=frame, velocities=v)
    return sim


def test_a_runaway_is_caught_and_the_last_checkpoint_is_within_the_bound(tmp_path):
    comm = Communicator()
    sim = _lattice(comm)
    dt = 3.0 * sim.dt_critical
    sim.set_dt(dt)
    writer = CheckpointWriter(lambda: restart.payload(sim), str(tmp_path / "ck"), every_steps=1, keep=2)
    with pytest.raises(InstabilityError, match="NaN or speed above the limit"):
        sim.run(20000, operations=[writer])
    assert writer.written, "the run wrote checkpoints before it blew up"
    # the bound at this dt: 0.1 R per step (no plates: no loading speed)
    limit = STEP_DISPLACEMENT * R / dt
    assert sim.speed_limit == pytest.approx(limit, rel=1e-12)
    blown = sim.step_count
    last = writer.written[-1]
    loaded = restart.load(comm, last)
    n = loaded.elements.n_owned
    speed = np.sqrt((loaded.elements.v[:n] ** 2).sum(axis=1)).max()
    assert speed <= limit, (speed, limit)
    assert np.all(np.isfinite(loaded.elements.x[:n]))
    # the checkpoint is the step just before the blow-up was seen (checkpoints at every step)
    assert loaded.step_count == blown - 1
    # and it restarts: at a stable step the run goes on, its speeds bounded
    loaded.set_dt(0.5 * loaded.dt_critical)
    loaded.run(200)
    assert np.sqrt((loaded.elements.v[:n] ** 2).sum(axis=1)).max() <= limit


def test_the_bound_follows_the_time_step_and_the_plates():
    """``speed_limit`` is 0.1 r_min / dt at every dt (``set_dt``), at most ``max_speed``, and at
    least ``LOADING_SPEEDS`` times the plates' speed."""
    comm = Communicator()
    sim = _lattice(comm)
    assert sim.speed_limit == pytest.approx(1e4)          # before a run: max_speed alone
    sim.run(0)
    assert sim.speed_limit == pytest.approx(STEP_DISPLACEMENT * R / sim.dt, rel=1e-12)
    sim.set_dt(0.5 * sim.dt)
    assert sim.speed_limit == pytest.approx(STEP_DISPLACEMENT * R / sim.dt, rel=1e-12)
    sim.set_dt(1e-12)
    assert sim.speed_limit == pytest.approx(1e4)           # max_speed is the cap

    class Plates:
        speed = 200.0
    sim.set_dt(1e-6)
    sim.plates = Plates()
    sim._set_speed_limit()
    assert sim.speed_limit == pytest.approx(max(STEP_DISPLACEMENT * R / 1e-6, LOADING_SPEEDS * 200.0))
