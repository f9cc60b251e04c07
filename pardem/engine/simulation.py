"""The time loop: a ``Simulation`` advances the state and runs operations (HOOMD style).

``Simulation.step`` is the only place that sequences kernels and communication; its docstring is
the recipe of one step (ARCHITECTURE.md repeats it). Around the steps, ``run`` calls:

* fixes (``sim.fixes``, objects with ``post_force(sim)``; ``pardem.engine.fixes``): inside every
  force evaluation, after all interaction forces: external loads, gravity, clamps, imposed motion;
* operations (``Operation``: writers, progress, logs, checks, servo updaters): after the steps
  on which their ``trigger`` (``pardem.triggers``) is true, and once at the end of a ``run``
  for those whose ``at_end`` is true, in list order (``sim.operations`` first, then those given to
  ``run``); never otherwise.
"""
import math
import os
import time as _time
from typing import Protocol

import numpy as np

from pardem.config import DeckError
from pardem.engine import stop
from pardem.parallel import watchdog
from pardem.errors import InjectedFault, InstabilityError, Interrupted
from pardem.engine.particles import Particles, reduce_globals
from pardem.triggers import At, as_trigger
from pardem.parallel import exact_sum
from pardem.physics import exact_accumulate, walls
from pardem.physics.finite import first_nonfinite
from pardem.physics.beam import compute_bonds
from pardem.physics.viscous_damping import damp_elements
from pardem.physics.verlet import kick, kick_drift, kinetic_energy


class Operation(Protocol):
    """Something run between steps: writers (``pardem.io``), samplers, protocol updaters.

    ``__call__(sim)`` runs on every rank (it may use collectives) after each step on which
    ``trigger`` is true: a ``pardem.triggers.Trigger`` of the step count, or an int n for
    ``Periodic(n)``. ``at_end`` (optional, default False): also run once at the end of every
    ``run`` (after its last step, or at once for ``run(0)``), for an operation that must see the
    state a run leaves (a sampler's last row, a servo's update); an operation due on the last step
    runs once. ``run`` calls it on no other step.
    """
    trigger: object
    at_end: bool = False

    def __call__(self, sim: "Simulation") -> None: ...


class FaultInjection:
    """Operation raising on one rank at one step, from ``PARDEM_FAULT=rank:step`` (for tests).

    Lets a test check that a failure on one rank ends every rank promptly.
    """

    def __init__(self, rank, step):
        self.rank, self.step = int(rank), int(step)
        self.trigger = At(self.step)     # looked at on that step only

    @classmethod
    def from_environment(cls):
        """The injection asked by ``PARDEM_FAULT`` (None when unset or empty); ``DeckError`` (one
        line naming the variable and its form) when malformed: drivers call this before any output."""
        spec = os.environ.get("PARDEM_FAULT", "").strip()
        if not spec:
            return None
        parts = spec.split(":")
        if len(parts) != 2 or not all(p.strip().isdigit() and p.strip().isascii() for p in parts):
            raise DeckError(f"PARDEM_FAULT = {spec!r}: expected RANK:STEP, two integers >= 0 (e.g. 1:200)")
        return cls(*parts)

    def __call__(self, sim):
        if sim.comm.rank == self.rank and sim.step_count == self.step:
            raise InjectedFault(f"fault injected on rank {self.rank} at step {self.step} (PARDEM_FAULT)")


def _trigger_of(op):
    """The trigger of operation ``op`` (ValueError, naming it, without one)."""
    if not hasattr(op, "trigger"):
        raise ValueError(f"operation {op!r} has no trigger: expected a ``trigger`` attribute (an int "
                         f"period >= 1 or a pardem.triggers.Trigger)"
                         + ("; ``every`` is no longer read: give ``trigger`` instead" if hasattr(op, "every") else ""))
    return as_trigger(op.trigger, f"trigger of {type(op).__name__}")


# the default largest displacement of an element in one step, as a fraction of the smallest
# radius: more is a runaway, not motion the step resolves (docs/physics.md, "Stability check")
STEP_DISPLACEMENT = 0.1
# ... unless the loading itself drives the elements that fast: a plate moving at v makes speeds of
# the order of v, never this many times more
LOADING_SPEEDS = 10.0


class Simulation:
    """Bonded and contacting elements (between plates, or in a periodic cell) on one rank.

    dt [s] must already be checked against the critical step. The run is declared unstable when
    an element moves more than ``max_step_displacement`` (default ``STEP_DISPLACEMENT``) of the
    smallest radius in one step
    (``|v| dt``, checked at every step of ``run``; or more than ``LOADING_SPEEDS`` times the
    plates' speed, if that is more), or faster than ``max_speed`` [m/s] (default: far above any
    physical DEM speed).
    Optional parts: ``plates`` (``state.Plates``), ``contacts`` (``pardem.engine.contacts.Contacts``),
    ``cell`` (``pardem.engine.periodic_cell.PeriodicCell``), ``viscous_damping`` rate C [1/s] (global
    drag ``-C m v``, ``-C I w``, for sample preparation).

    ``orientation`` False: the orientations ``elements.q`` are not integrated; they keep the values
    they had (and outputs write those). No contact or wall law reads them, so the positions,
    velocities and spins are bitwise those of a run that integrates them; bonds read them, so
    bonded elements need it True (ValueError). LAMMPS' ``fix nve/sphere`` likewise integrates the
    spin but no orientation. Saves ~10 % of a granular step (the quaternion update of the drift).
    """

    def __init__(self, comm, elements, bonds, plates, dt, max_speed=1e4, check_every=50, domain=None,
                 contacts=None, cell=None, viscous_damping=0.0, orientation=True,
                 max_step_displacement=STEP_DISPLACEMENT):
        self.comm = comm
        self.elements = elements
        self.bonds = bonds
        self.plates = plates
        self.dt = float(dt)
        self.time = 0.0
        self.step_count = 0
        self._clock = (0, 0.0)          # (step, time) from which time counts at the current dt
        self.bond_energy = 0.0
        self.plate_energy = 0.0
        self.max_speed2 = float(max_speed) * float(max_speed)   # inf, not OverflowError, past 1e154
        self.step_displacement = float(max_step_displacement)
        self._speed_limit2 = self.max_speed2    # with the displacement bound once ``run`` knows r_min
        self._r_min = None              # the smallest radius [m] over ranks (``run``)
        self.check_every = int(check_every)
        self._unstable = False
        self.seconds_computing = 0.0   # in the kernels (communication excluded)
        self.domain = domain           # the parallel layer (SlabComm) or None on a single process
        self.contacts = contacts
        if contacts is not None and plates is not None:
            contacts.sort_rows = False     # wall forces are summed in row order
        self.cell = cell
        self.viscous_damping = float(viscous_damping)
        self.orientation = bool(orientation)
        if not self.orientation and comm.any(bonds is not None and bonds.n > 0):
            raise ValueError("orientation = False: bonds read the elements' orientations; expected "
                             "orientation = True when there are bonds")
        self.contact_energy = 0.0
        self.stress = np.zeros((3, 3))  # Love-Weber stress of the contacts [Pa] (servo cells only)
        self.bonds_broken_step = 0      # bonds broken by the last force call, counted on this rank
        self.pairs_freed = False        # a bond broke since the last contact list build
        self.fixes = []                 # objects with post_force(sim): loads, clamps (engine.fixes)
        # set by the builder (pardem.engine.system.build) or the restore: the description of the
        # system (model only, no particle arrays), the grains' density [kg/m^3], the critical
        # step [s], the contact reach and ghost range [m]
        self.system = None
        self.density = None
        self.dt_critical = None
        self.reach = None
        self.ghost_range = None
        self.n_elements = None          # the global element count at the build or restore
        self.operations = []            # operations run by every ``run`` (writers, logs, ...)
        self._globals_step = -1         # step of the last ``_reduce_globals``
        # the forces of the step-0 state are computed (by the first ``run``): a second run from
        # step 0 must not add them again, nor move the tangential springs twice
        self.initial_forces = False
        self.forces_restored = False    # set by a restore: the forces are the checkpoint's

    @property
    def particles(self):
        """The particle arrays by global id, global on every rank (``pardem.engine.particles.
        Particles``: ``positions`` [N, 3] [m], ..., ``get``, ``set``, ``add_property``, ``local``)."""
        return Particles(self)

    def _reduce_globals(self, again=False):
        """Collective: the global wall forces (``walls.force``) and fix reactions
        (``global_reaction``) of the last force evaluation, one allreduce
        (``particles.reduce_globals``); once per step (``run`` and ``step`` both ask at a run's end)
        unless ``again`` (``run(0)`` at step 0 computes the forces without a step)."""
        if again or self._globals_step != self.step_count:
            self._globals_step = self.step_count
            reduce_globals(self)

    def compute_forces(self, with_energy=True):
        """Forces and torques of the current configuration (after ``f``, ``t`` were zeroed).

        Without ``with_energy`` the contact energy of this step is not computed (NaN): ``run``
        asks for it only on the steps after which an operation runs.
        """
        e, p = self.elements, self.plates
        if self.bonds is not None and self.bonds.n:
            self.bond_energy, broken, counted = compute_bonds(self.bonds, e)
            self.bonds_broken_step = counted
            if broken:
                # a bond held by two ranks breaks on both (identical inputs) and is counted on
                # one; the freed pair must enter the contact list at the next step
                self.pairs_freed = True
        if p is not None:
            # walls move at the velocity of the half step, the instant of the element velocities
            normals, offsets, velocities = p.planes(self.time + 0.5 * self.dt)
            self.plate_energy = walls.compute(p.law, e, normals, offsets, velocities, e.wall_h,
                                              self.dt, p.wall_force)
            m = len(p.force_local)
            p.force_local[:] = -np.einsum("wd,wd->w", p.wall_force[:m], normals[:m])
            if getattr(p, "shapes", False):    # cylinders and meshes of an API wall set
                self.plate_energy += p.compute_shapes(e, self.time + 0.5 * self.dt, self.dt)
        if self.contacts is not None:
            self.contact_energy = self.contacts.compute(e, self.dt, with_energy)
        if self.viscous_damping > 0.0:
            damp_elements(e, self.viscous_damping)
        for fix in self.fixes:
            fix.post_force(self)

    def rebuild_contacts(self):
        """Single process: wrap into the periodic cell and rebuild the contact list."""
        e = self.elements
        if first_nonfinite([e.x[:e.n_owned]]) >= 0:
            # a blown-up row cannot be binned: the run stops as unstable (the slab layer's update
            # reports the same through ``unstable``)
            self._unstable = True
            self.check_stability(force=True)
        if self.cell is not None:
            self.cell.wrap(self.elements)
        self.contacts.sort(self.elements, self.bonds)     # rows in spatial order (when sort_rows)
        self.contacts.rebuild(self.elements, self.bonds)
        self.pairs_freed = False

    def _reference_positions(self):
        if self.domain is not None:
            return (self.domain.x_build,)
        return (self.contacts.reference_positions(),) if self.contacts is not None else ()

    def _drift_reference(self):
        """The positions of the last list build when the rebuild check may measure the
        displacements during the drift (None when nothing checks, or when the cell's affine
        step moves the rows after the drift)."""
        refs = () if self.cell is not None and self.cell.deforming else self._reference_positions()
        ref = refs[0] if refs else None
        # before the first build the list's reference has no rows
        return ref if ref is not None and ref.shape[0] >= self.elements.n_owned else None

    def step(self, with_energy=True):
        """Advance one step of velocity Verlet (collective on several ranks). In this order:

        1. first half kick and drift of the owned rows (``physics.verlet.kick_drift``), which also
           measures the largest displacement since the last list build for step 4's check
           (unless the cell deforms: step 2 moves the rows again, and the check measures then);
        2. the periodic cell's affine deformation (``PeriodicCell.deform``), the slab cuts follow it;
        3. the plates and walls move to their position at the end of the step;
        4. communication: the slab layer migrates elements and rebuilds ghosts and the contact list
           when an element moved half a skin (or a bond broke, or a rebalance is due), otherwise it
           refreshes the ghosts (``SlabComm.update``); on one process, the contact list's rebuild
           check instead;
        5. forces (``compute_forces``): bonds, walls, contacts, global viscous damping, then fixes;
        6. the cell's stress servo from the global Love-Weber stress (one allreduce);
        7. second half kick; the largest speed is checked against ``max_speed`` (reduced every
           ``check_every`` steps by ``run``);
        8. with the energy only: the global wall forces and fix reactions (``_reduce_globals``).

        ``with_energy``: compute the contact energy of this step, and reduce the global wall forces
        and reactions (``run`` asks only on steps after which an operation runs, LAMMPS' eflag).
        """
        t0 = _time.perf_counter()
        e = self.elements
        # no kernel of the step reads the rotation matrices (the bond loop makes them from q):
        # ``Elements.rot`` is refreshed on demand (``refresh_rotations``)
        ref = self._drift_reference()
        moved2 = kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, self.dt,
                            e.n_owned, False, ref, self.orientation)
        if ref is None:
            moved2 = None        # measured after the cell's step, by the check itself
        if self.cell is not None:
            factor = self.cell.deform(e, self.dt, self._reference_positions())
            if factor is not None and self.domain is not None:
                self.domain.follow_cell(factor)
        if self.plates is not None:
            # the time at the end of this step, as ``self.time`` will be (also after ``set_dt``)
            self.plates.move_to(self._clock[1] + (self.step_count + 1 - self._clock[0]) * self.dt)
        t1 = _time.perf_counter()
        if self.domain is not None:
            # migration and ghosts, or the ghost refresh
            u = self.domain.update(self.step_count, e, self.bonds, self.contacts, self.pairs_freed,
                                   self._unstable, self.seconds_computing, moved2)
            if u.unstable:
                self.check_stability(force=True)
            if u.rebuilt:
                self.elements, self.bonds = u.elements, u.bonds
                if self.contacts is not None:
                    self.pairs_freed = False    # the freed pairs are in the new contact list
                e = self.elements
        elif self.contacts is not None and (self.pairs_freed or self.contacts.needs_rebuild(e, moved2)):
            self.rebuild_contacts()
        t2 = _time.perf_counter()
        self.compute_forces(with_energy)
        if self.cell is not None and self.cell.servo is not None:
            self.stress = self.global_stress()
            self.cell.control(self.stress, self.dt)
        vmax2 = kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, self.dt, e.n_owned)
        self.seconds_computing += (t1 - t0) + (_time.perf_counter() - t2)
        if not vmax2 <= self._speed_limit2:
            self._unstable = True
        self.step_count += 1
        # not a running sum: no drift, exact on restart
        self.time = self._clock[1] + (self.step_count - self._clock[0]) * self.dt
        if with_energy:
            self._reduce_globals()      # walls.force, fix.global_reaction for the operations

    def set_dt(self, dt):
        """Change the time step [s] from the next step on (adaptive relaxation); the caller is
        responsible for its stability. Time stays continuous."""
        self._clock = (self.step_count, self.time)
        self.dt = float(dt)
        self._set_speed_limit()

    def _set_speed_limit(self):
        """The speed above which a step is a runaway [m/s], squared: ``max_speed``, and, once
        ``run`` has measured ``r_min``, ``step_displacement r_min / dt`` (or ``LOADING_SPEEDS``
        times the plates' speed, if more) when that is less."""
        limit2 = self.max_speed2
        # without anything stiff (no bond, wall or contact: an infinite critical step) no
        # interaction has a motion per step to resolve: a free flight is never a runaway
        dt_c = getattr(self, "dt_critical", None)     # None: not known here (built by a protocol)
        stiff = dt_c is None or math.isfinite(dt_c)
        if self._r_min is not None and self.dt > 0.0 and stiff:
            loading = LOADING_SPEEDS * abs(float(getattr(self.plates, "speed", 0.0) or 0.0))
            bound = max(self.step_displacement * self._r_min / self.dt, loading)
            limit2 = min(limit2, bound * bound)
        self._speed_limit2 = limit2

    @property
    def speed_limit(self):
        """The speed [m/s] above which the run is declared unstable (``step_displacement`` of the
        smallest radius per step, at most ``max_speed``); ``max_speed`` before the first ``run``."""
        return float(np.sqrt(self._speed_limit2))

    @property
    def unstable(self):
        """This rank saw a NaN or a runaway speed, or (at the last check) a non-finite field (not
        yet reduced over ranks)."""
        return self._unstable

    def check_stability(self, force=False, stop_requests=False):
        """Collective: raise ``InstabilityError`` on every rank if any rank blew up: a runaway or
        NaN speed seen by a kick, or a NaN or infinity in any evolving field (``evolving_fields``,
        scanned here: about one memory pass, every ``check_every`` steps and before checkpoints).

        ``force``: the caller already knows from a collective that some rank did.
        ``stop_requests``: also raise ``Interrupted`` on every rank if any rank received a stop
        signal (``pardem.engine.stop``), in the same reduction.
        """
        signum = self._stability_and_stop(force, stop_requests)
        if signum:
            raise Interrupted(signum, self.step_count)

    def _stability_and_stop(self, force=False, stop_requests=False):
        """``check_stability``'s reduction: raises ``InstabilityError`` on every rank; returns the
        stop signal some rank received (``stop_requests``), the same on every rank, or 0."""
        if force:
            unstable, signum = True, 0
        else:
            self._check_finite()   # every evolving field, not only the speeds of the last kick
            if stop_requests:
                flags = self.comm.max_array([float(self._unstable), float(stop.requested())])
                unstable, signum = bool(flags[0]), int(flags[1])
            else:
                unstable, signum = self.comm.any(self._unstable), 0
        if unstable:
            raise InstabilityError(
                f"at step {self.step_count} (t = {self.time:.6g} s): NaN or speed above the limit "
                f"({self.speed_limit:.4g} m/s: {self.step_displacement:g} of the smallest radius per step or "
                f"{LOADING_SPEEDS:g} times the plates' speed, at most max_speed: Integration.max_step_displacement "
                f"and max_speed set them; or a non-finite position, "
                f"velocity, force or state)")
        return signum

    def evolving_fields(self):
        """(name, array) of every field the steps change on this rank: the owned rows' x, v, w, q,
        f, t and wall history, the bonds' plastic strain, the contact history, the cell and plates."""
        e, n = self.elements, self.elements.n_owned
        fields = [("x", e.x[:n]), ("v", e.v[:n]), ("w", e.w[:n]), ("q", e.q[:n]), ("f", e.f[:n]),
                  ("t", e.t[:n])]
        if e.wall_h is not None and e.wall_h.shape[1]:
            fields.append(("wall_h", e.wall_h[:n]))
        if self.bonds is not None and self.bonds.n:
            fields.append(("bond plastic strain", self.bonds.plastic))
        if self.contacts is not None:
            fields.append(("contact history", self.contacts.history))
        if self.cell is not None:
            fields += [("cell length", self.cell.length), ("cell strain", self.cell.strain)]
        if self.plates is not None:
            # Plates hold their positions in an array, API walls their plane offsets
            pos = self.plates.positions
            fields.append(("plate positions", pos if isinstance(pos, np.ndarray) else self.plates.offsets))
        return fields

    def _check_finite(self):
        """Mark this rank unstable if an evolving field holds a NaN or an infinity (local)."""
        if not self._unstable:
            fields = self.evolving_fields()
            self._unstable = first_nonfinite([a for _, a in fields]) >= 0

    def global_stress(self):
        """Love-Weber stress of the contacts over the cell [3, 3] [Pa], tension positive
        (collective; from the sums of the last force evaluation; exact, the same bits on any
        number of ranks, when the contacts are ``reproducible``)."""
        sums = self.contacts.global_sums(self.comm)[0] if self.contacts is not None else np.zeros(9)
        return np.asarray(sums).reshape(3, 3) / self.cell.volume

    def kinetic_energy(self):
        """Kinetic energy of all elements [J] (collective). Summed exactly, the same bits on any
        number of ranks, when the contacts are ``reproducible`` (its decisions feed back)."""
        e = self.elements
        if self.contacts is not None and self.contacts.reproducible:
            acc = exact_accumulate.zeros(1)
            ok = exact_accumulate.kinetic_terms(e.v, e.w, e.mass, e.inertia, e.n_owned, acc)
            return float(exact_sum.total(self.comm, acc, ok)[0])
        return float(self.comm.sum(kinetic_energy(e.v, e.w, e.mass, e.inertia, e.n_owned)))

    def run(self, n_steps, operations=()):
        """Advance ``n_steps`` steps (an integer >= 0), running ``self.operations`` then
        ``operations`` (``Operation``) after the steps their triggers select, and those with
        ``at_end`` once at the end.

        The contact energies are computed (LAMMPS' eflag) on the steps after which an operation
        runs and on the last step (the state the caller gets back: a checkpoint stores them).
        Between those steps the loop costs one integer comparison a step: each trigger's
        ``next_after`` says the next step to look at.

        Stop signals (``pardem.engine.stop``) are reduced over ranks with the stability check,
        every ``check_every`` steps and at the last step; a stop raises ``Interrupted`` on every
        rank at that step once its operations have run (on the last step, the ``at_end`` ones
        too), so the state it leaves is the one the uninterrupted run has there: a checkpoint of
        it continues that run bit for bit, whatever the operations change (FIRE's step, a servo,
        a sampler's rows).
        """
        if (isinstance(n_steps, (bool, np.bool_)) or not isinstance(n_steps, (int, np.integer))
                or n_steps < 0):
            raise ValueError(f"n_steps = {n_steps!r}: expected an integer >= 0 (steps to run)")
        if n_steps > 0:
            self.forces_restored = False
        operations = list(self.operations) + list(operations)
        triggers = [_trigger_of(op) for op in operations]
        at_end = [bool(getattr(op, "at_end", False)) for op in operations]
        e = self.elements
        # collective, every run: a script may change radii (``particles.set``) between runs
        self._r_min = float(self.comm.min(float(e.radius[:e.n_owned].min()) if e.n_owned else np.inf))
        if not np.isfinite(self._r_min):
            self._r_min = None
        self._set_speed_limit()
        if self.step_count == 0 and not self.initial_forces:
            if self.contacts is not None and self.domain is None and self.contacts.vl.builds == 0:
                self.rebuild_contacts()
            e = self.elements
            e.f[:] = 0.0            # a state restored at step 0 holds the stored forces
            e.t[:] = 0.0
            self.compute_forces()   # forces of the initial state for the first half kick
            self.initial_forces = True
        end = self.step_count + int(n_steps)
        look = [t.next_after(self.step_count) for t in triggers]   # None: never again
        due = min((s for s in look if s is not None), default=None)
        ran = ()
        stopping = 0      # a stop signal every rank agreed on at this step
        while self.step_count < end:
            after = self.step_count + 1
            ran = ()
            if after == due:
                # the operations whose trigger is true on this step (triggers are pure functions
                # of the step, so they are asked before the step: it must know the energy flag)
                ran = [i for i, s in enumerate(look) if s == after and triggers[i](after)]
                for i, s in enumerate(look):
                    if s == after:
                        look[i] = triggers[i].next_after(after)
                due = min((s for s in look if s is not None), default=None)
            self.step(with_energy=bool(ran) or after == end)
            watchdog.beat()          # this rank's progress, for the watchdog and the signal handler
            if self.step_count % self.check_every == 0 or self.step_count == end:
                stopping = self._stability_and_stop(stop_requests=True)
            if self.step_count != end:
                for i in ran:
                    operations[i](self)
                if stopping:
                    # after this step's operations, as a periodic checkpoint of it would see them
                    watchdog.pause()
                    raise Interrupted(stopping, self.step_count)
        self._reduce_globals(again=self.step_count == 0)   # walls.force, fix.global_reaction: end of run
        # the last step's operations with the at_end ones, in list order, each once
        for i, op in enumerate(operations):
            if at_end[i] or i in ran:
                op(self)
        watchdog.pause()    # out of the time loop: the caller may do long serial work now
        if stopping:
            raise Interrupted(stopping, self.step_count)
