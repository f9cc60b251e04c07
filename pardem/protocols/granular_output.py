"""The output and restart contract shared by the granular drivers (``isotropic``, ``triaxial``).

The same contract as ``pardem.drivers.compress``: checkpoints through
``pardem.io.checkpoint_writer.CheckpointWriter`` (deck ``[checkpoint]``), ``--restart`` from one of
them (the file is checked complete and written by the same driver, the deck compatible), ``--steps``
to stop a run early (it leaves a checkpoint to continue from), ParaView snapshots (``[output]
vtk_every``), a series as CSV and HDF5 with units, a summary JSON and a plot.

A protocol keeps its own state (stage, counters, results so far) in a JSON-friendly dict; the
checkpoint stores it as the root attribute ``protocol`` next to the granular case
(``pardem.restart.payload``), and the series rows so far in ``/series``.
"""
import json
import os
import time

import numpy as np

from pardem.errors import StepLimit  # noqa: F401 - the protocols raise it from here
from pardem.config import DeckError, Field, auto_or, choice, number, positive, restart_differences
from pardem import restart
from pardem.protocols import deck_checks
from pardem.protocols.output_deck import CHECKPOINT_SECTION  # noqa: F401 - the granular schemas read it here
from pardem.io import checkpoint
from pardem.io.series import SeriesCSV, dict_row
from pardem.io.series_h5 import SeriesH5
from pardem.triggers import At, Or


def dimension_value(name, v):
    """Deck checker of ``domain.dimension``: the integer 2 or 3."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v not in (2, 3):
        raise DeckError(f"{name} = {v!r}: expected 2 (spheres with centres in the plane z = 0, moving in "
                        "x, y and turning about z) or 3")
    return int(v)


dimension_value.options = (2, 3)

# the [domain] section of the granular decks (pardem.engine.plane: the 2D mode)
DOMAIN_SECTION = {
    "dimension": Field(3, dimension_value,
                       "3, or 2: spheres (full mass and inertia, 3D contact laws) with centres in the "
                       "plane z = 0, moving in x, y and turning about z; the cell is periodic in x, y and "
                       "stresses are per unit area of the plane over the mean diameter [Pa]"),
}


def domain_checks(deck):
    """Whole-deck check of the 2D mode: the slabs are stacked along x or y (all centres lie at z = 0)."""
    if deck["domain"]["dimension"] == 2 and deck["run"]["slab_axis"] == "z":
        raise DeckError("run.slab_axis = 'z': expected 'x' or 'y' with domain.dimension = 2 (the grains "
                        "lie in the plane z = 0)")


def copies_value(name, v):
    """Deck checker of ``replicate.copies``: two integers in [1, 100]."""
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or any(isinstance(k, bool) or not isinstance(k, (int, float)) or k != int(k) or not 1 <= k <= 100
                   for k in v)):
        raise DeckError(f"{name} = {v!r}: expected [k_x, k_y], two integers in [1, 100] (copies along x and y)")
    return [int(k) for k in v]


copies_value.options = None

# the [replicate] section of the 2D decks (pardem.engine.replicate: larger packings without a new
# preparation)
REPLICATE_SECTION = {
    "copies": Field([1, 1], copies_value, "copies [k_x, k_y] of the periodic packing (pardem.engine."
                                          "replicate) before the boundaries are made; [1, 1]: none"),
}


def run_section(dt_help, skin_help):
    """The [run] section of a granular deck: time step fraction (``dt_help`` says of which critical
    step), skin (``skin_help``: its auto value), slab axis, progress and watchdog periods."""
    return {
        "dt_fraction": Field(0.25, number(0.0, 1.0, hi_open=False), f"time step as a fraction of the {dt_help}"),
        "skin": Field("auto", auto_or(positive()), f"Verlet skin [m] ({skin_help})"),
        "slab_axis": Field("x", choice("x", "y", "z"), "axis the MPI slabs are stacked along: x, y or z"),
        "progress_seconds": Field(10.0, positive(), "seconds between progress lines (rank 0)"),
        "watchdog_seconds": deck_checks.WATCHDOG_FIELD,
    }

STEPS_HELP = ("stop the run at step N, counted from its start over all stages, and write a checkpoint "
              "to continue from with --restart (default: run the protocol to its end)")


def restart_help(may_change):
    """The --restart help of a granular driver whose restart may change the keys ``may_change``."""
    return ("continue the run of this checkpoint; its deck is used unless --config is given, and --set "
            "may change only " + ", ".join(may_change) + " and the [output] and [checkpoint] keys")


def deck_differences(old, new, schema, may_change=(), may_change_sections=("output", "checkpoint")):
    """``(section.key, old, new)`` of the keys whose values differ between two checked decks and
    may not on restart (``pardem.config.restart_differences`` with these drivers' default sections)."""
    return restart_differences(schema, old, new, may_change, may_change_sections)


def inspect_restart(path, driver, comm=None):
    """The checked attributes of checkpoint ``path`` (``checkpoint.inspect``) with its protocol
    state decoded (``meta["protocol"]``). CheckpointError when it is incomplete, unreadable or not
    a checkpoint of ``driver``."""
    meta = checkpoint.inspect(path, comm=comm)
    raw = meta.get("protocol")
    state = json.loads(raw) if isinstance(raw, (str, bytes)) else raw
    if not isinstance(state, dict) or state.get("driver") != driver:
        found = state.get("driver") if isinstance(state, dict) else None
        raise checkpoint.CheckpointError(
            f"--restart {path}: not a checkpoint of the {driver} driver"
            + (f" (written by the {found} driver)" if found else ""))
    meta["protocol"] = state
    return meta


def check_restart(path, meta, deck, schema, steps, may_change, what):
    """DeckError when the restart's deck would change the physics or ``--steps`` is before the
    checkpoint; ``what`` names the keys that may change (for the message)."""
    if steps is not None and steps <= int(meta["step"]):
        raise DeckError(f"--steps {steps} is not after the checkpoint's step {int(meta['step'])}: --steps "
                        f"counts the run's total steps from its start")
    diffs = deck_differences(meta["deck"], deck, schema, may_change)
    if diffs:
        name, old, new = diffs[0]
        raise DeckError(f"{name} = {new!r} differs from the checkpoint's {old!r}: a restart may change "
                        f"only {what} and the output and checkpoint settings")


def payload(case, deck, state, series_rows, columns):
    """``(groups, series, attrs)`` of the case plus the protocol's state and the series so far."""
    groups, _, attrs = restart.payload(case.sim, extras=case.extras)
    attrs["deck"] = deck
    attrs["protocol"] = state
    series = {k: np.asarray([r[k] for r in series_rows], dtype=np.float64) for k in columns}
    return groups, series, attrs


def rows_of(series, columns, int_columns=()):
    """The series rows (dicts) of a checkpoint's ``/series`` columns."""
    n = min((len(series[k]) for k in columns if k in series), default=0)
    return [{k: (int(series[k][i]) if k in int_columns else float(series[k][i])) for k in columns}
            for i in range(n)]


class Series:
    """Rank 0's series: ``NAME.csv`` and ``NAME.h5`` (units) in ``out``, rewritten from the rows of
    a restarted run, plus the rows in memory (for the checkpoints). ``append`` skips a row of a
    step already written (a run resumed at a check it had recorded)."""

    def __init__(self, comm, out, name, columns, units, description, rows=(), int_columns=("step",)):
        self.columns, self.rows = tuple(columns), list(rows)
        self.root = comm.is_root
        self.csv = self.h5 = None
        self.paths = [os.path.join(out, f"{name}.csv"), os.path.join(out, f"{name}.h5")]
        if self.root:
            row = dict_row(self.columns)
            self.csv = SeriesCSV(self.paths[0], self.columns, row, units=units)
            for r in self.rows:
                self.csv.append(r)
            self.h5 = SeriesH5(self.paths[1], self.rows, self.columns, units, row, description,
                               int_columns=set(int_columns))

    def append(self, row):
        if self.rows and self.rows[-1]["step"] == row["step"]:
            return
        self.rows.append(row)
        if self.root:
            self.csv.append(row)
            self.h5.append(row)

    def close(self):
        if self.root:
            self.csv.close()
            self.h5.close()


class StageClock:
    """Wall seconds and steps per stage of a run, kept across restarts (``state()`` is JSON-able
    and includes the current stage so far; a restart continues from it)."""

    def __init__(self, state=None):
        st = state or {}
        self.seconds = dict(st.get("seconds", {}))
        self.steps = dict(st.get("steps", {}))
        self.current = None      # (name, t0, step0)

    def enter(self, name, step):
        """Start (or continue) stage ``name`` at ``step``; the previous one ends here."""
        self.close(step)
        self.current = (name, time.perf_counter(), int(step))

    def close(self, step):
        if self.current is not None:
            name, t0, s0 = self.current
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0
            self.steps[name] = self.steps.get(name, 0) + int(step) - s0
            self.current = None

    def state(self, step):
        """``{"seconds": {stage: s}, "steps": {stage: n}}`` up to now (the current stage included)."""
        sec, steps = dict(self.seconds), dict(self.steps)
        if self.current is not None:
            name, t0, s0 = self.current
            sec[name] = sec.get(name, 0.0) + time.perf_counter() - t0
            steps[name] = steps.get(name, 0) + int(step) - s0
        return {"seconds": sec, "steps": steps}

    def summary(self, step, n_elements):
        """The summary's timing keys up to ``step``: ``stage_seconds``, ``stage_steps``,
        ``seconds_per_step`` and ``element_steps_per_second`` per stage; ``n_elements(stage)`` is
        the number of elements that stage stepped."""
        st = self.state(step)
        sec, steps = st["seconds"], st["steps"]
        return {"stage_seconds": sec, "stage_steps": steps,
                "seconds_per_step": {k: sec[k] / steps[k] if steps.get(k) else None for k in sec},
                "element_steps_per_second": {k: n_elements(k) * steps[k] / sec[k] if steps.get(k) and sec[k] > 0
                                             else None for k in sec}}


class RowSampler:
    """Operation appending ``sample()`` (a dict with ``"step"``) to ``rows`` every ``every`` steps
    and at the step ``final``, then calling ``on_row(row)``; a step already recorded is not
    recorded again, so a run cut in pieces samples the steps of the uncut run."""

    def __init__(self, sample, every, final, rows, on_row=None):
        self.sample, self.rows, self.on_row = sample, rows, on_row
        self.trigger = Or([every, At(final)])
        self.at_end = False

    def __call__(self, sim):
        if self.rows and self.rows[-1]["step"] == sim.step_count:
            return
        row = self.sample()
        self.rows.append(row)
        if self.on_row is not None:
            self.on_row(row)
