"""Triggers (``pardem.triggers``) and how ``Simulation.run`` calls operations.

Oracles: the triggers' definitions written out as plain Python predicates over a range of steps
(brute force), and, for ``run``, the list of steps on which each operation must run counted by
hand from the definition (trigger steps among those a run completes, plus its last step for
``at_end``), each operation at most once a step.
"""
import os

import numpy as np
import pytest

import pardem
from pardem.triggers import After, And, At, Before, Never, Not, Or, Periodic, Trigger, as_trigger
from pardem.io.paraview import ParaViewWriter

HORIZON = 240          # steps over which the brute-force twin is compared


def brute_cases():
    """(trigger, predicate) pairs: the predicate is the definition, written independently."""
    per = [(p, f) for p in (1, 2, 3, 7, 50) for f in (0, 1, 5, 13)]
    cases = [(Periodic(p, phase=f), lambda s, p=p, f=f: s >= f and (s - f) % p == 0) for p, f in per]
    cases += [
        (At([0, 3, 17, 17, 230]), lambda s: s in (0, 3, 17, 230)),
        (At(5), lambda s: s == 5),
        (At([]), lambda s: False),
        (Never(), lambda s: False),
        (After(10), lambda s: s > 10),
        (Before(10), lambda s: s < 10),
        (Before(0), lambda s: False),
        (Or([Periodic(7), At([3, 100])]), lambda s: s % 7 == 0 or s in (3, 100)),
        (Periodic(6) | 10, lambda s: s % 6 == 0 or s % 10 == 0),
        (And([Periodic(6), Periodic(4)]), lambda s: s % 12 == 0),
        (Periodic(6) & After(50) & Before(200), lambda s: s % 6 == 0 and 50 < s < 200),
        (And([Periodic(2), Periodic(2, phase=1)]), lambda s: False),          # never together
        (And([Periodic(97), Periodic(89)]), lambda s: s % (97 * 89) == 0),   # beyond And's look-ahead
        # from step 0 And's look-ahead gives up on step 128, just before the common step
        (And([Not(Periodic(2)), Periodic(2) | At(129)]), lambda s: s == 129),
        (Not(Periodic(3)), lambda s: s % 3 != 0),
        (~After(20), lambda s: s <= 20),
        (~Never(), lambda s: True),
        (Or([Not(Periodic(5)), At(15)]) & Before(40), lambda s: (s % 5 != 0 or s == 15) and s < 40),
        (And([Or([Periodic(4), At(9)]), Not(Periodic(8))]), lambda s: (s % 4 == 0 or s == 9) and s % 8 != 0),
    ]
    return cases


@pytest.mark.parametrize("trigger,truth", brute_cases(), ids=lambda x: repr(x) if isinstance(x, Trigger) else "")
def test_trigger_is_its_definition_and_next_after_agrees(trigger, truth):
    """``trigger(s)`` is the definition on every step; ``next_after(s)`` never skips a true step
    (false strictly between), is None only when no true step follows, and following it from step 0,
    asking the trigger at each step it names (as ``run`` does), finds exactly the true steps."""
    want = [s for s in range(HORIZON + 1) if truth(s)]
    assert [s for s in range(HORIZON + 1) if trigger(s)] == want
    for s in range(HORIZON):
        n = trigger.next_after(s)
        later = [t for t in want if t > s]
        if n is None:
            assert not later, (s, later[:3])
            continue
        assert n > s
        assert not [t for t in later if t < n], (s, n)
    # the walk of run(): look only where next_after points
    found, s = [], 0
    while True:
        n = trigger.next_after(s)
        if n is None or n > HORIZON:
            break
        if trigger(n):
            found.append(n)
        s = n
    assert found == [t for t in want if t > 0]


@pytest.mark.parametrize("trigger", [Periodic(7, phase=3), At([4, 9, 200]), Never(), After(12), Before(30),
                                     Or([Periodic(9), At(5)]), And([Periodic(6), Periodic(4)])])
def test_next_after_is_exact_for_the_primitives_and_their_combinations(trigger):
    """For these the next look is the next true step itself (no wasted look in ``run``)."""
    for s in range(HORIZON):
        n = trigger.next_after(s)
        want = next((t for t in range(s + 1, 20 * HORIZON) if trigger(t)), None)
        assert n == want, s


def test_int_stands_for_periodic_and_bad_triggers_are_refused():
    assert as_trigger(5) == Periodic(5) and as_trigger(np.int64(3)) == Periodic(3)
    t = At([2, 4])
    assert as_trigger(t) is t
    assert Periodic(4, phase=1) != Periodic(4) and At([1, 2]) == At([2, 1, 2])
    for bad in (0, -3, 2.5, True, None, "10", [10]):
        with pytest.raises(ValueError, match=r"trigger = .*: expected a period, an integer >= 1"):
            as_trigger(bad)
    with pytest.raises(ValueError, match="period = 0: expected an integer >= 1"):
        Periodic(0)
    with pytest.raises(ValueError, match="phase = -1: expected an integer >= 0"):
        Periodic(3, phase=-1)
    with pytest.raises(ValueError, match="steps = -2: expected an integer >= 0"):
        At([1, -2])
    with pytest.raises(ValueError, match="steps = 1.5"):
        At(1.5)
    with pytest.raises(ValueError, match="step = 2.0"):
        After(2.0)
    with pytest.raises(ValueError, match="Or operand = 0"):
        Or([Periodic(2), 0])


# -- Simulation.run ----------------------------------------------------------------------------

R, RHO = 0.01, 1000.0


def one_sphere():
    """A free sphere (no bonds, no walls): a step costs little and nothing can go unstable."""
    system = pardem.System(pardem.Particles([[0.0, 0.0, 1.0]], R, RHO, velocities=[[0.1, 0.0, 0.0]]),
                           integration=pardem.Integration(dt=1e-4))
    return pardem.build(pardem.Communicator(), system)


class Record:
    """Operation recording the steps it runs on (into ``log`` shared by several, with its name)."""

    def __init__(self, trigger, at_end=False, name="op", log=None):
        self.trigger, self.at_end, self.name = trigger, at_end, name
        self.log = [] if log is None else log
        self.steps = []

    def __call__(self, sim):
        self.steps.append(sim.step_count)
        self.log.append((self.name, sim.step_count))


def test_many_short_runs_write_only_the_trigger_steps(tmp_path):
    """400 runs of 50 steps with a ParaView writer every 500 steps: the snapshots of steps 500,
    1000, ..., 20000 (40), not one per run (400 with the former implicit call at each run's end)."""
    sim = one_sphere()
    pv = ParaViewWriter(tmp_path, sim.comm, trigger=500)
    for _ in range(400):
        sim.run(50, [pv])
    names = sorted(n for n in os.listdir(tmp_path) if n.endswith(".pvtu"))
    assert names == [f"snapshot-{s:08d}.pvtu" for s in range(500, 20001, 500)]
    assert sorted(pv.snapshots) == list(range(500, 20001, 500))


def test_at_end_runs_once_after_each_run_and_never_twice():
    sim = one_sphere()
    log = []
    periodic = Record(10, name="periodic", log=log)
    ending = Record(10, at_end=True, name="ending", log=log)
    only_end = Record(Never(), at_end=True, name="only_end", log=log)
    sim.operations.append(Record(At(25), name="sim_op", log=log))
    sim.run(25, [periodic, ending, only_end])
    sim.run(5, [periodic, ending, only_end])      # ends on 30, a trigger step of both periodic ones
    sim.run(0, [periodic, ending, only_end])      # no step: only the at_end operations, at once
    assert periodic.steps == [10, 20, 30]
    assert ending.steps == [10, 20, 25, 30, 30]   # 25: end of run 1; 30 once for run 2, once for run(0)
    assert only_end.steps == [25, 30, 30]
    # on a step, the operations run in list order (sim.operations first), the at_end ones among them
    assert log[log.index(("sim_op", 25)):log.index(("only_end", 25)) + 1] == [
        ("sim_op", 25), ("ending", 25), ("only_end", 25)]
    assert log[-5:] == [("periodic", 30), ("ending", 30), ("only_end", 30), ("ending", 30), ("only_end", 30)]


def test_run_looks_only_at_due_steps_and_computes_energies_there():
    """The trigger is asked only on the steps ``next_after`` names (not every step), and the step
    computes its energies only when an operation runs after it, or on the run's last step."""
    asked = []

    class Counted(Periodic):
        def __call__(self, step):
            asked.append(step)
            return super().__call__(step)

    sim = one_sphere()
    flags = []
    step = sim.step

    def spy(with_energy=True):
        flags.append((sim.step_count + 1, with_energy))
        step(with_energy)
    sim.step = spy
    op = Record(Counted(100, phase=30))
    sim.run(1000, [op])
    assert asked == list(range(30, 1001, 100)) and op.steps == asked
    assert [s for s, e in flags if e] == asked + [1000]


def test_run_refuses_bad_step_counts_and_operations_without_trigger():
    sim = one_sphere()
    for bad in (-5, 2.7, True, "3", None, np.float64(4.0)):
        with pytest.raises(ValueError, match=r"n_steps = .*: expected an integer >= 0"):
            sim.run(bad)
    assert sim.step_count == 0
    sim.run(np.int64(3))
    assert sim.step_count == 3

    class Old:
        every = 10

        def __call__(self, sim):
            pass
    with pytest.raises(ValueError, match="has no trigger.*every.*no longer read"):
        sim.run(10, [Old()])
    with pytest.raises(ValueError, match="trigger of Record = 0"):
        sim.run(10, [Record(0)])
    assert sim.step_count == 3


def test_a_second_run_from_step_0_does_not_add_the_initial_forces_again():
    """``run(0)`` computes the forces of the initial state; a later run from step 0 starts from
    them, not from their double (and a loaded sphere falls as if run once)."""
    once, twice = one_sphere(), one_sphere()
    for sim in (once, twice):
        pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -9.81)))
    twice.run(0)
    twice.run(0)
    once.run(20)
    twice.run(20)
    assert np.array_equal(once.elements.x, twice.elements.x)
    assert np.array_equal(once.elements.v, twice.elements.v)
    # a fix added after run(0) acts on the initial forces at once, as between later runs
    late = one_sphere()
    late.run(0)
    pardem.add_fixes(late, pardem.Gravity((0.0, 0.0, -9.81)))
    late.run(20)
    assert np.array_equal(once.elements.x, late.elements.x)
