"""Thermo log: one line per call with the step, time, energies and user columns (LAMMPS' thermo).

``Log`` is an operation (``trigger`` and ``at_end`` attributes, ``__call__(sim)``): pass it to
``sim.run(n, operations=[log])`` or append it to ``sim.operations``. ``Simulation.run`` calls it on
every rank, after the steps its trigger selects and, as LAMMPS' thermo output, once after the last
step of every run (``at_end``, default True); the call is collective (the energies are summed over
ranks with ``sim.comm.sum``), and rank 0 alone prints and writes.

Columns: ``step``, ``time`` [s], ``kinetic`` (translational + rotational kinetic energy [J]),
``bond`` (elastic energy of the intact bonds [J]), ``contact`` (elastic energy of the
element-element contacts [J]), ``wall`` (elastic energy of the element-wall contacts [J]),
``potential`` (gravitational potential energy ``-sum m g . x`` [J] of the gravity fixes, zero at
the origin), ``total`` (the sum of all five [J]: constant in a run without dissipation, gravity
included, up to the Verlet error), then the user columns in the order given.

Only the energies the simulation can have are printed (``energies=None``): ``kinetic`` always,
``bond`` with bonds, ``contact`` with a contact model, ``wall`` with walls or plates,
``potential`` with a gravity fix (a fix with a uniform acceleration ``g`` [3] [m/s^2], as
``engine.fixes.Gravity``, or one with a ``potential_energy(sim)`` method giving this rank's share
[J]); ``energies="all"`` or a tuple of names asks for others. ``total`` sums every energy, printed
or not. A grain wrapped through a periodic boundary along ``g`` changes the potential by
``m g L``: the potential is that of the wrapped positions. Dissipated energy is not logged (the
dashpots, friction and drag would need a sum at every step, which a writer does not see).
Integer values (``step``, and user columns returning Python or NumPy integers) are printed as
integers.

Each bond is counted once: on several ranks a bond crossing a slab boundary is computed by both
ranks, so its energy is recomputed here on the rank owning its first end only (an extra pass over
the bonds at each log line, not at every step; one rank needs none). Contacts already count each
pair once and walls act on owned rows only.

File: ``directory/log.txt`` (created with the directory if needed), whitespace-separated columns
under a ``# step time ...`` header line (``numpy.loadtxt`` reads it). An existing log.txt is never
overwritten unless asked: ``mode="append"`` (the default, for restarts) appends a new header line
``# continued at step N`` and then the lines; ``mode="new"`` refuses (FileExistsError on every rank)
when the file exists; ``mode="overwrite"`` truncates it.

A restarted run's log reads as one run with ``read_log(path)``: a segment ``# continued at step N``
(N the step of its first line) replaces the earlier lines of steps >= N (the earlier run went on
past the checkpoint it was restarted from; the restarted run logs those steps again, with the same
values since a restart continues bit for bit), so every step appears once, in order.
"""
import dataclasses
import os
import sys

import numpy as np

from pardem.triggers import as_trigger
from pardem.physics.beam import compute_bonds
from pardem.physics.verlet import kinetic_energy

ENERGIES = ("kinetic", "bond", "contact", "wall", "potential")
COLUMNS = ("step", "time", *ENERGIES, "total")
MODES = ("append", "new", "overwrite")


def _gravity_fixes(sim):
    return [f for f in getattr(sim, "fixes", ()) if hasattr(f, "potential_energy")
            or np.shape(getattr(f, "g", None)) == (3,)]


def potential_energy(sim):
    """This rank's gravitational potential energy [J]: ``-sum m g . x`` over the owned rows for
    each fix with a uniform acceleration ``g`` (``engine.fixes.Gravity``), or the fix's own
    ``potential_energy(sim)``."""
    e = sim.elements
    n = e.n_owned
    total = 0.0
    for fix in _gravity_fixes(sim):
        if hasattr(fix, "potential_energy"):
            total += float(fix.potential_energy(sim))
        else:
            total -= float(np.sum(e.mass[:n] * (e.x[:n] @ np.asarray(fix.g, dtype=np.float64))))
    return total


def energies(sim):
    """``{"kinetic", "bond", "contact", "wall", "potential"}`` [J] of the last force evaluation,
    summed over ranks (collective: every rank must call it; every rank gets the same values)."""
    e = sim.elements
    ke = kinetic_energy(e.v, e.w, e.mass, e.inertia, e.n_owned)
    bond = _bond_energy_once(sim)
    contact = sim.contact_energy if sim.contacts is not None else 0.0
    wall = sim.plate_energy if sim.plates is not None else 0.0
    s = np.asarray(sim.comm.sum([ke, bond, contact, wall, potential_energy(sim)]))
    return dict(zip(ENERGIES, (float(v) for v in s)))


def present_energies(sim):
    """The energies the simulation can have (collective): kinetic; bond with bonds on any rank;
    contact with a contact model; wall with plates or walls; potential with a gravity fix."""
    b = sim.bonds
    n_bonds = sim.comm.sum([0.0 if b is None else float(b.n)])[0]
    have = {"kinetic": True, "bond": n_bonds > 0, "contact": sim.contacts is not None,
            "wall": sim.plates is not None, "potential": bool(_gravity_fixes(sim))}
    return tuple(k for k in ENERGIES if have[k])


def read_log(path):
    """The lines of a ``log.txt`` as one run: ``(names, rows [n, k] float64)``, ``names`` the
    header's columns. A segment ``# continued at step N`` (a restart's ``append``; N its first
    line's step) drops the earlier lines of steps >= N; its header must name the same columns
    (ValueError otherwise)."""
    names, rows = None, []
    with open(path) as fh:
        for line in fh:
            text = line.strip()
            if not text:
                continue
            if text.startswith("# continued at step"):
                step = int(text.split()[-1])
                rows = [r for r in rows if r[0] < step]
            elif text.startswith("#"):
                header = tuple(text[1:].split())
                if names is not None and header != names:
                    raise ValueError(f"{path}: a continued segment has columns {' '.join(header)}, "
                                     f"the file began with {' '.join(names)}")
                names = header
            else:
                rows.append([float(v) for v in text.split()])
    return names, np.array(rows, dtype=np.float64).reshape(-1, len(names or ()))


def _bond_energy_once(sim):
    b = sim.bonds
    if b is None or b.n == 0:
        return 0.0
    if sim.comm.size == 1:
        return float(sim.bond_energy)
    e = sim.elements
    once = b.counted_once(e.n_owned)
    if once.all():
        return float(sim.bond_energy)
    if not once.any():
        return 0.0
    # the same kernel on this rank's share, into scratch force arrays (the state is copied, so
    # rupture or densification flags of the copy are thrown away)
    sub = dataclasses.replace(b, **{f.name: getattr(b, f.name)[once] for f in dataclasses.fields(b)
                                    if isinstance(getattr(b, f.name), np.ndarray)})
    scratch = dataclasses.replace(e, f=np.zeros_like(e.f), t=np.zeros_like(e.t))
    energy, _, _ = compute_bonds(sub, scratch)
    return float(energy)


class Log:
    """Operation writing one thermo line per call (see the module docstring).

    directory : where ``log.txt`` goes (None: no file); trigger : the steps of the lines (an int
    period [steps] or a ``pardem.triggers.Trigger``); at_end : also a line after the last
    step of every run (a step already logged is not logged twice); columns : dict
    ``{name: function(sim) -> float}`` of user columns, called on **every** rank (so a function may
    use collectives such as ``sim.comm.sum``; rank 0's value is written); stream : where rank 0
    prints (default ``"stdout"``: the ``sys.stdout`` of the moment; None: no printing); mode : "append" (default), "new" or
    "overwrite" for an existing log.txt; precision : significant digits of the values;
    energies : the energy columns printed (None: those the simulation can have; "all"; or a tuple
    of names from ``ENERGIES``). ``rows`` keeps every line written by this object (rank 0; list of
    tuples), ``names`` the columns (set at the first line when ``energies`` is None).
    """

    def __init__(self, directory=None, trigger=100, columns=None, stream="stdout", mode="append",
                 precision=10, at_end=True, energies=None):
        trigger = as_trigger(trigger)
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        if isinstance(energies, str) and energies == "all":
            energies = ENERGIES
        if energies is not None:
            if not isinstance(energies, (tuple, list)) or not all(isinstance(k, str) and k in ENERGIES
                                                                  for k in energies):
                raise ValueError(f"energies must be None, 'all' or a tuple of names from "
                                 f"{', '.join(ENERGIES)}; got {energies!r}")
            energies = tuple(k for k in ENERGIES if k in energies)
        columns = dict(columns or {})
        for name, fn in columns.items():
            if not isinstance(name, str) or not name or any(c.isspace() for c in name) or name in COLUMNS:
                raise ValueError(f"column names must be non-empty strings without spaces, other than "
                                 f"{', '.join(COLUMNS)}; got {name!r}")
            if not callable(fn):
                raise ValueError(f"column {name!r} must be a function sim -> float, got {type(fn).__name__}")
        self.trigger, self.at_end = trigger, bool(at_end)
        self.directory = directory
        self.columns = columns
        self.energies = energies
        self.names = None if energies is None else ("step", "time", *energies, "total", *columns)
        self.stream = stream
        self.mode = mode
        self.precision = int(precision)
        self.rows = []
        self._file = None
        self._opened = False
        self._last_step = None

    @property
    def out(self):
        """The stream rank 0 prints to (None: none)."""
        return sys.stdout if isinstance(self.stream, str) and self.stream == "stdout" else self.stream

    @property
    def path(self):
        return None if self.directory is None else os.path.join(self.directory, "log.txt")

    def _open(self, sim):
        """Open the file on rank 0 (collective: a refusal raises on every rank)."""
        self._opened = True
        if self.energies is None:
            self.energies = present_energies(sim)
            self.names = ("step", "time", *self.energies, "total", *self.columns)
        err = None
        if sim.comm.is_root and self.directory is not None:
            try:
                os.makedirs(self.directory, exist_ok=True)
                exists = os.path.exists(self.path) and os.path.getsize(self.path) > 0
                if exists and self.mode == "new":
                    err = f"{self.path} exists: refusing to overwrite it (mode='new'); use mode='append' " \
                          f"to continue it or mode='overwrite' to replace it"
                else:
                    self._file = open(self.path, "a" if self.mode == "append" else "w")
                    if exists and self.mode == "append":
                        self._file.write(f"# continued at step {sim.step_count}\n")
                    self._file.write("# " + " ".join(self.names) + "\n")
                    self._file.flush()
            except OSError as exc:
                err = f"cannot write {self.path}: {exc}"
        err = sim.comm.bcast(err)
        if err is not None:
            raise FileExistsError(err) if "refusing" in err else OSError(err)
        if sim.comm.is_root and self.out is not None:
            self.out.write(self._format_header() + "\n")
            self.out.flush()

    def _format_header(self):
        w = self.precision + 7
        return f"{'step':>10} " + " ".join(f"{n:>{w}}" for n in self.names[1:])

    def _format(self, values):
        w = self.precision + 7
        return f"{int(values[0]):>10d} " + " ".join(
            f"{v:>{w}d}" if isinstance(v, int) else f"{v:>{w}.{self.precision - 1}e}" for v in values[1:])

    def values(self, sim):
        """The line's values (collective): the printed columns' (``names``)."""
        if self.energies is None:
            self.energies = present_energies(sim)
            self.names = ("step", "time", *self.energies, "total", *self.columns)
        en = energies(sim)
        total = sum(en[k] for k in ENERGIES)
        user = [_number(fn(sim)) for fn in self.columns.values()]
        return (int(sim.step_count), float(sim.time), *(en[k] for k in self.energies), total, *user)

    def __call__(self, sim):
        if not self._opened:
            self._open(sim)
        if self._last_step == sim.step_count:
            return
        self._last_step = sim.step_count
        row = self.values(sim)
        if not sim.comm.is_root:
            return
        self.rows.append(row)
        line = self._format(row)
        if self._file is not None:
            self._file.write(line + "\n")
            self._file.flush()
        if self.out is not None:
            self.out.write(line + "\n")
            self.out.flush()

    def close(self):
        if self._file is not None:
            self._file.close()
            self._file = None


def _number(v):
    """A user column's value: an int for an integer (not a bool), else a float."""
    if isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)):
        return int(v)
    return float(v)


__all__ = ["Log", "energies", "read_log", "COLUMNS", "ENERGIES"]
