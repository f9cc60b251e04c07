"""The thermo log's energies (pardem.io.log): the total, gravitational potential included, is
conserved by an undamped bouncing ball within velocity Verlet's error bound; the log's columns are
the energies the model can have; integers print as integers; a restarted log reads as one run."""
import numpy as np
import pytest

import pardem
from pardem.io.log import read_log

from _util import bonded_sim

R, RHO, K, G = 1e-3, 2500.0, 1e5, 9.81
M = RHO * 4 / 3 * np.pi * R**3
OMEGA = np.sqrt(K / M)
DROP = 3 * R            # free fall before the first touch [m]


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def ball(comm, dt_fraction, restitution=1.0):
    """A sphere of radius R released at rest 3 R above an undamped linear wall (z = 0), gravity -z."""
    mat = pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=0.0)
    sim = bonded_sim(comm, [[0.0, 0.0, R + DROP]], R, RHO, np.zeros((0, 2), int), mat,
                     dt_fraction=dt_fraction, walls=dict(normals=[[0, 0, 1]], points=[[0, 0, 0]],
                                                         stiffness=K, restitution=restitution))
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -G)))
    return sim


def bounce(comm, dt_fraction):
    """The log rows of a fall, one bounce and half the way up again, one line per step."""
    sim = ball(comm, dt_fraction)
    log = pardem.Log(trigger=1, stream=None)
    fall = np.sqrt(2 * DROP / G)
    sim.run(int((2 * fall + np.pi / OMEGA) / sim.dt), operations=[log])
    return sim, log.names, np.array(log.rows)


def test_total_energy_is_conserved_under_gravity(comm):
    spreads = []
    for fraction in (0.1, 0.05):
        sim, names, rows = bounce(comm, fraction)
        assert names == ("step", "time", "kinetic", "wall", "potential", "total")
        kin, wall, pot, total = (rows[:, names.index(k)] for k in ("kinetic", "wall", "potential", "total"))
        z = R + DROP - 0.5 * G * rows[:, 1] ** 2
        free = wall == 0.0
        first_touch = np.argmax(~free)
        # the potential is -m g . x of the centre: m G z in free fall (the analytic height)
        np.testing.assert_allclose(pot[:first_touch], M * G * z[:first_touch], rtol=1e-9)
        assert 0 < first_touch < len(rows) and (~free).sum() > 10 and free[-1]
        E = M * G * DROP                       # the energy the fall exchanges
        # velocity Verlet exact under a constant force: constant to rounding before the touch (a
        # few ulps of the position per step, accumulating at most linearly)
        eps = np.finfo(float).eps
        np.testing.assert_allclose(total[:first_touch], total[0], rtol=0,
                                   atol=4 * eps * first_touch * total[0])
        assert kin[first_touch - 1] == pytest.approx(E, rel=0.2)
        w_dt = OMEGA * sim.dt
        # through the contact: Verlet conserves a shadow energy; on a linear spring the true
        # energy departs from it by at most (omega dt)^2 / 4 of the contact's energy (~E); the
        # touch and release inside a step add as much again: bound (omega dt)^2 / 2 of E
        spread = np.ptp(total)
        assert spread <= 0.5 * w_dt**2 * E
        spreads.append(spread)
    # second order: half the step, a quarter of the spread (the events' share varies: 3 to 5)
    assert 3.0 < spreads[0] / spreads[1] < 5.0


def test_zero_columns_are_left_out_unless_asked_and_integers_print_as_integers(comm, tmp_path):
    sim = ball(comm, 0.1)
    log = pardem.Log(tmp_path, trigger=5, stream=None, columns={"touching": lambda s: int(s.elements.x[0, 2] < R)})
    sim.run(10, operations=[log])
    log.close()
    lines = (tmp_path / "log.txt").read_text().splitlines()
    assert lines[0].split() == ["#", "step", "time", "kinetic", "wall", "potential", "total", "touching"]
    assert [ln.split()[-1] for ln in lines[1:]] == ["0", "0"]
    every = pardem.Log(trigger=5, stream=None, energies="all")
    some = pardem.Log(trigger=5, stream=None, energies=("bond", "kinetic"))
    sim.run(5, operations=[every, some])
    assert every.names == ("step", "time", "kinetic", "bond", "contact", "wall", "potential", "total")
    assert some.names == ("step", "time", "kinetic", "bond", "total")
    assert every.rows[0][3] == every.rows[0][4] == 0.0
    assert every.rows[0][-1] == some.rows[0][-1]       # the total sums every energy either way
    for bad in ("some", ("heat",), 3):
        with pytest.raises(ValueError, match="energies must be"):
            pardem.Log(energies=bad)


def test_a_restarted_log_reads_as_one_run(comm, tmp_path):
    """A run logged to step 40, restarted from its checkpoint at step 20: read_log drops the first
    run's lines after 20, and the lines equal the uninterrupted run's."""
    ref = ball(comm, 0.1)
    whole = pardem.Log(tmp_path / "ref", trigger=5, stream=None)
    ref.run(60, operations=[whole])
    whole.close()
    sim = ball(comm, 0.1)
    first = pardem.Log(tmp_path / "run", trigger=5, stream=None)
    sim.run(20, operations=[first])
    pardem.save(sim, tmp_path / "ck.h5")
    sim.run(20, operations=[first])         # past the checkpoint, then stopped
    first.close()
    again = pardem.load(comm, tmp_path / "ck.h5")
    # the checkpoint's forces already hold the gravity (fixes are not stored): appended, not
    # add_fixes, which would apply it to them once more
    again.fixes.append(pardem.Gravity((0.0, 0.0, -G)))
    second = pardem.Log(tmp_path / "run", trigger=5, stream=None)
    again.run(40, operations=[second])
    second.close()
    names, rows = read_log(tmp_path / "run" / "log.txt")
    ref_names, ref_rows = read_log(tmp_path / "ref" / "log.txt")
    assert names == ref_names and list(rows[:, 0]) == list(range(5, 61, 5))
    np.testing.assert_array_equal(rows, ref_rows)    # a restart continues bit for bit
    raw = np.loadtxt(tmp_path / "run" / "log.txt")   # the file itself keeps both runs' lines
    assert len(raw) == len(rows) + 4
