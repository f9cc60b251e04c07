"""The stages of a granular protocol, and the relaxation stage they share.

**One shape for protocols with several stages.** A protocol names its stages in order (e.g. the
biaxial test's ``prepare, open, settle, load``); its driver keeps the name of the current stage in
the protocol's state (which every checkpoint stores) and ``run_stages`` runs them from there. A
stage function runs its stage to its end from wherever the state says it is: from the start, or,
resumed from a checkpoint written inside it, from that checkpoint's step with what the checkpoint
holds (the FIRE operation's counters and the step its relaxation started at, in ``SweepRun.state``;
the cell's servo and its stiffness cap, the time step and the contact history, in the case).
``--steps`` stops a stage at that step (``StepLimit``) and the run's final checkpoint resumes it
there, bit for bit.

**The relaxation stage** (``prepare``, ``relax``; docs/physics.md sections 8, 11): the deck's
gas (``build_gas``: ``pardem.domains.gas`` on rank 0, broadcast) or a packing brought to static
equilibrium at a pressure p0 by the periodic cell's servo, with FIRE (``pardem.engine.relaxation``)
or viscous damping, until the kinetic, force and pressure criteria hold (``pardem.engine.packing
.balance``). ``pardem.protocols.isotropic`` describes it; the isotropic, biaxial and point-load
response protocols and the mixture study run it.
"""
import numpy as np

from pardem.domains.gas import gas
from pardem.engine import granular
from pardem.engine.packing import balance
from pardem.engine.relaxation import Fire, ServoStiffness
from pardem.engine.system import Cell, ContactModel, Decomposition, Integration, Particles, System
from pardem.physics import hertz_mindlin
from pardem.physics.contact_laws import critical_time_step
from pardem.protocols.granular_output import StepLimit
from pardem.triggers import as_trigger

DONE = "done"     # the stage name of a finished sequence


def run_stages(state, stages, resume=False, key="stage"):
    """Run the stages ``stages`` (ordered ``(name, function)`` pairs) from ``state[key]`` on, to
    the end (``state[key] = DONE``). ``function(resume)`` runs its stage to its end and returns the
    name of the stage that follows, or None for the next one of the list; ``resume`` is true for
    the first stage run when ``state`` is a checkpoint's (that stage continues where the checkpoint
    was written). ``state[key]`` names the stage being run until it ends, so a checkpoint written
    in it (or after a ``StepLimit`` or a stop signal, which pass through) resumes it."""
    names = [name for name, _ in stages]
    table = dict(stages)
    if len(table) != len(names) or DONE in table:
        raise ValueError(f"run_stages: stage names must be distinct and not {DONE!r}, got {names}")
    while state[key] != DONE:
        name = state[key]
        if name not in table:
            raise ValueError(f"run_stages: unknown stage {name!r} (expected one of {names})")
        nxt = table[name](resume)
        resume = False
        if nxt is None:
            k = names.index(name) + 1
            nxt = names[k] if k < len(names) else DONE
        state[key] = nxt


def replay(sim, operations, at_end=False):
    """Run the operations of ``operations`` due on the current step (and with ``at_end`` those
    whose ``at_end`` is true), in list order. For the checkpoints of a stop signal written by
    earlier versions, whose ``sim.run`` ended after a step and before that step's operations: a
    run resumed from one runs them first, as the uninterrupted run did (FIRE's mixing, the servo
    stiffness, a sample). ``sim.run`` now runs them before it stops. Collective."""
    k = sim.step_count
    for op in operations:
        if as_trigger(op.trigger)(k) or (at_end and getattr(op, "at_end", False)):
            op(sim)


class Paused:
    """An operation run by a ``sim.run`` that stops inside a stage (``--steps``): its trigger as
    usual, but not its ``at_end`` (the run is paused, not ended: an uninterrupted run would not
    run it there, e.g. ``ServoStiffness``, and the resumed run must see the same state)."""
    at_end = False

    def __init__(self, op):
        self.op = op
        self.trigger = op.trigger

    def __call__(self, sim):
        self.op(sim)


def skin(deck, radii):
    """The Verlet skin [m] of the deck for these radii ("auto" = 0.2 x the smallest)."""
    v = deck["run"]["skin"]
    return 0.2 * float(np.min(radii)) if v == "auto" else float(v)


def young_modulus(material):
    return 2.0 * material["shear_modulus"] * (1.0 + material["poisson"])


def contact_params(material, friction, restitution=1.0):
    """The ``hertz_mindlin`` parameters dict of the deck's grains."""
    return {"young": young_modulus(material), "poisson": material["poisson"],
            "friction": float(friction), "restitution": float(restitution)}


FIRE_STATE = ("alpha", "downhill", "restarts", "dt_stable", "calls")


class SweepRun:
    """The state of a sweep that a checkpoint holds (``state``, JSON friendly: pressure index,
    stage, the step its relaxation started at, the increment's stresses, results so far; ``fire``
    is the live FIRE operation), and what a driver adds to the protocol's runs: ``operations``
    (checkpoint and ParaView writers), ``on_check(sim, balance)`` after every equilibrium check,
    ``stop``: the step the run stops at (``StepLimit``, at the first check at or after it; with
    ``exact_stop``, at that step, inside a check interval if need be).

    ``state``: a checkpoint's (the sweep then continues it); None starts the sweep. A state
    holding ``replay`` (a stop signal's checkpoint written by an earlier version, whose stop left
    its step's operations undone) makes the resumed relaxation first run them (``replay``).
    """

    def __init__(self, operations=(), on_check=None, stop=None, state=None, exact_stop=False):
        self.operations = list(operations)
        self.on_check = on_check
        self.stop = stop
        self.exact_stop = bool(exact_stop)
        self.resuming = state is not None
        self.state = state if state is not None else {
            "driver": "isotropic", "index": 0, "stage": "prepare", "start": 0, "fire": None,
            "rows": [], "details": [], "row": None, "det": None, "moduli": None,
            "increment": None, "done": False}
        self.replay = bool(self.state.pop("replay", False))
        self.fire = None

    def snapshot(self, interrupted=False):
        """The state to store now (the FIRE operation's counters included). ``interrupted`` (a
        stop signal ended the run) changes nothing: ``sim.run`` stops after the operations of
        its last step, so a stop's checkpoint resumes as any other."""
        out = dict(self.state)
        out["fire"] = None if self.fire is None else {k: getattr(self.fire, k) for k in FIRE_STATE}
        return out

    def before_run(self, sim):
        if self.stop is not None and sim.step_count >= self.stop:
            raise StepLimit(f"stopped at step {sim.step_count} (--steps {self.stop})")


def relax(sim, tol, check_every, max_steps, p0=None, progress=None, label="", operations=(),
          start=None, run=None):
    """Run (with ``operations``) until the kinetic and force criteria (and with ``p0`` the
    pressure one) hold, checked every ``check_every`` steps from the step ``start`` (default: now).

    A relaxation resumed from a checkpoint (``start`` before now) first completes the interval
    it was in; resumed at a check, it makes that check without running. ``run``: the
    ``SweepRun`` (its operations, checks and stop; stopped inside an interval by ``exact_stop``, the
    run resumed from that step completes the interval). Returns ``(balance dict, converged,
    steps)``; collective.
    """
    start = sim.step_count if start is None else int(start)
    ops = list(operations) + (run.operations if run is not None else [])
    first = True
    while True:
        done = sim.step_count - start
        at_check = first and done > 0 and done % check_every == 0
        if first and run is not None and getattr(run, "replay", False):
            # an earlier version's stop checkpoint; at a check the uninterrupted run's sim.run
            # ended there: its at_end operations too
            replay(sim, ops, at_end=at_check)
            run.replay = False
        first = False
        if not at_check:
            n = check_every - done % check_every
            if run is not None:
                run.before_run(sim)
                if getattr(run, "exact_stop", False) and run.stop is not None and sim.step_count + n > run.stop:
                    sim.run(run.stop - sim.step_count, [Paused(op) for op in ops])
                    run.before_run(sim)      # StepLimit
            sim.run(n, ops)
        steps = sim.step_count - start
        b = balance(sim, p0)
        ok = b["kinetic"] < tol["kinetic_tolerance"] and b["unbalanced"] < tol["force_tolerance"]
        if p0 is not None:
            ok = ok and abs(b["pressure"] / p0 - 1.0) < tol["pressure_tolerance"]
        if progress is not None:
            progress.report(sim.step_count, f"{label}: p = {b['pressure']:.6g} Pa, "
                            f"E_k/(N p0 V) = {b['kinetic']:.3g}, unbalanced = {b['unbalanced']:.3g}, "
                            f"contacts {b['n_contacts']}, cell rate {sim.cell.rate[0]:.3g} 1/s")
        if run is not None and run.on_check is not None:
            run.on_check(sim, b)
        if ok or steps >= max_steps:
            return b, bool(ok), steps


def dimension(deck):
    """The deck's ``domain.dimension`` (3 for a deck written before the 2D mode)."""
    return int(deck.get("domain", {}).get("dimension", 3))


def build_gas(comm, deck):
    """The granular case of the deck's gas (frictionless, damped, servo off; ``case.extras["dt"]`` the
    run's step [s])."""
    s, mat, run = deck["sample"], deck["material"], deck["run"]
    dim = dimension(deck)
    data = None
    if comm.is_root:
        data = gas(s["n"], s["radii"], s["fractions"], s["gas_solid_fraction"], s["seed"], dim=dim,
                   aspect=s.get("aspect_ratio", 1.0))
    pos, radii, edge = comm.bcast(data)
    params = contact_params(mat, 0.0, mat["restitution"])
    dt_c = critical_time_step("hertz_mindlin", hertz_mindlin.Params(**params), radii, s["density"])
    dt = run["dt_fraction"] * dt_c
    system = System(Particles(pos, radii, s["density"]), contacts=ContactModel("hertz_mindlin", params),
                    cell=Cell(np.zeros(3), edge), dimension=dim,
                    integration=Integration(dt=dt, viscous_damping=deck["preparation"]["damping"]),
                    decomposition=Decomposition(slab_axis="xyz".index(run["slab_axis"]), skin=skin(deck, radii)))
    # the run's base step, which FIRE's adaptive step leaves (a restart during the preparation reads it)
    case = granular.build_case(comm, system, extras={"dt": dt})
    return case


def prepare(comm, deck, p0, case=None, progress=None, run=None, resume=False):
    """Bring the deck's gas (or the packing of ``case``) to static equilibrium at ``p0`` [Pa].

    Frictionless contacts (history cleared), the servo at p0 with viscous damping, until the three
    criteria of ``pardem.protocols.isotropic`` (step 3) hold (or ``preparation.max_steps``). The servo is then
    stopped, the cell fixed. Returns ``(case, info)`` with ``info`` the balance measures,
    ``converged`` and ``steps``. Collective. ``run``: the ``SweepRun``; ``resume``: continue the
    preparation its state was checkpointed in (``case`` restored from that checkpoint).
    """
    if case is None:
        case = build_gas(comm, deck)
    sim = case.sim
    prep, mat = deck["preparation"], deck["material"]
    c = sim.contacts
    c.params = hertz_mindlin.Params(**contact_params(mat, 0.0, mat["restitution"]))
    fire = prep["relaxation"] == "fire"
    sim.viscous_damping = 0.0 if fire else prep["damping"]
    if resume:
        dt = float(case.extras["dt"])   # the run's step (FIRE's current one is restored)
        start = int(run.state["start"])
    else:
        c.history[:] = 0.0
        sim.cell.servo = (float(p0), prep["servo_rate"] / float(p0), prep["max_rate"])
        dt = sim.dt
        start = sim.step_count
        if run is not None:
            run.state["start"] = start
    ops = [ServoStiffness()]
    if fire:
        ops.append(Fire(n_min=20, dt_max=prep["fire_max_dt"] * dt, dt_min=0.02 * dt))
        if resume and run.state.get("fire"):
            for k, v in run.state["fire"].items():
                setattr(ops[-1], k, v)
        if run is not None:
            run.fire = ops[-1]
    b, ok, steps = relax(sim, deck["equilibrium"], prep["check_every"], prep["max_steps"], p0=p0,
                         progress=progress, label=f"p0 = {p0:.3g} Pa", operations=ops, start=start,
                         run=run)
    if run is not None:
        run.fire = None
    sim.set_dt(dt)
    sim.viscous_damping = prep["damping"]
    sim.cell.servo = None
    sim.cell.servo_stiffness = 0.0
    sim.cell.rate = np.zeros(3)
    return case, {"balance": b, "converged": ok, "steps": steps}


__all__ = ["DONE", "run_stages", "replay", "Paused", "skin", "young_modulus", "contact_params", "dimension", "FIRE_STATE",
           "SweepRun", "relax", "build_gas", "prepare"]
