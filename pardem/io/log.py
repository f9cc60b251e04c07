"""Thermo log: one line per call with the step, time, energies and user columns (LAMMPS' thermo).

``Log`` is an operation (``trigger`` and ``at_end`` attributes, ``__call__(sim)``): pass it to
``sim.run(n, operations=[log])`` or append it to ``sim.operations``. ``Simulation.run`` calls it on
every rank, after the steps its trigger selects and, as LAMMPS' thermo output, once after the last
step of every run (``at_end``, default True); the call is collective (the energies are summed over
ranks with ``sim.comm.sum``), and rank 0 alone prints and writes.

Columns: ``step``, ``time`` [s], ``kinetic`` (translational + rotational kinetic energy [J]),
``bond`` (elastic energy of the intact bonds [J]), ``contact`` (elastic energy of the
element-element contacts [J]), ``wall`` (elastic energy of the element-wall contacts [J]),
``total`` (their sum [J]), then the user columns in the order given.

Each bond is counted once: on several ranks a bond crossing a slab boundary is computed by both
ranks, so its energy is recomputed here on the rank owning its first end only (an extra pass over
the bonds at each log line, not at every step; one rank needs none). Contacts already count each
pair once and walls act on owned rows only.

File: ``directory/log.txt`` (created with the directory if needed), whitespace-separated columns
under a ``# step time ...`` header line (``numpy.loadtxt`` reads it). An existing log.txt is never
overwritten unless asked: ``mode="append"`` (the default, for restarts) appends a new header line
``# continued at step N`` and then the lines; ``mode="new"`` refuses (FileExistsError on every rank)
when the file exists; ``mode="overwrite"`` truncates it.
"""
import dataclasses
import os
import sys

import numpy as np

from pardem.triggers import as_trigger
from pardem.physics.beam import compute_bonds
from pardem.physics.verlet import kinetic_energy

COLUMNS = ("step", "time", "kinetic", "bond", "contact", "wall", "total")
MODES = ("append", "new", "overwrite")


def energies(sim):
    """``{"kinetic", "bond", "contact", "wall"}`` [J] of the last force evaluation, summed over
    ranks (collective: every rank must call it; every rank gets the same values)."""
    e = sim.elements
    ke = kinetic_energy(e.v, e.w, e.mass, e.inertia, e.n_owned)
    bond = _bond_energy_once(sim)
    contact = sim.contact_energy if sim.contacts is not None else 0.0
    wall = sim.plate_energy if sim.plates is not None else 0.0
    s = np.asarray(sim.comm.sum([ke, bond, contact, wall]))
    return dict(zip(("kinetic", "bond", "contact", "wall"), (float(v) for v in s)))


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
    "overwrite" for an existing log.txt; precision : significant digits of the values.
    ``rows`` keeps every line written by this object (rank 0; list of tuples), ``names`` the columns.
    """

    def __init__(self, directory=None, trigger=100, columns=None, stream="stdout", mode="append",
                 precision=10, at_end=True):
        trigger = as_trigger(trigger)
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
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
        self.names = COLUMNS + tuple(columns)
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
        return f"{int(values[0]):>10d} " + " ".join(f"{v:>{w}.{self.precision - 1}e}" for v in values[1:])

    def values(self, sim):
        """The line's values (collective)."""
        en = energies(sim)
        total = en["kinetic"] + en["bond"] + en["contact"] + en["wall"]
        user = [float(fn(sim)) for fn in self.columns.values()]
        return (sim.step_count, float(sim.time), en["kinetic"], en["bond"], en["contact"], en["wall"],
                total, *user)

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


__all__ = ["Log", "energies", "COLUMNS"]
