"""The checkpoint operation: writes a case's checkpoints on a step and/or wall-clock period.

Generic: the case's ``payload()`` gives ``(groups, series, attrs)`` for
``pardem.io.checkpoint.write_checkpoint``; any protocol whose case can say what to store gets
checkpoints by adding this operation.
"""
import math
import os
import time

from pardem.config import Field, boolean, choice, number
from pardem.errors import OutputError
from pardem.triggers import Never, Periodic
from pardem.io import checkpoint

# the deck's [checkpoint] section of every driver that checkpoints: the writer's settings
DECK_SECTION = {
    "every_steps": Field(0, number(lo=0, lo_open=False, integer=True), "steps between checkpoints; 0 = off"),
    "every_seconds": Field(1800.0, number(lo=0.0, lo_open=False),
                           "wall seconds between checkpoints; 0 = off"),
    "keep": Field(3, number(lo=1, lo_open=False, integer=True), "how many checkpoints to keep"),
    "at_end": Field(True, boolean, "write a checkpoint when the run ends (also when --steps stops it)"),
    "at_stop": Field(True, boolean, "write a final checkpoint when a stop signal (SIGTERM, SIGINT, "
                                    "SIGUSR1) ends the run"),
    "driver": Field("auto", choice("auto", "mpio", "serial"),
                    "HDF5 writing: \"mpio\" (collective MPI-IO), \"serial\" (ranks take turns) or "
                    "\"auto\" (mpio when h5py is built with MPI)"),
}


# what this process's checkpoint writers did (the drivers' failure lines say which checkpoint a
# user can restart from): whether a writer exists, and the newest checkpoint written
_record = {"writer": False, "newest": None}


def forget():
    """Start a new record (``pardem.drivers.cli.run_driver``, at the start of a run)."""
    _record.update(writer=False, newest=None)


def newest():
    """``(writer, path)``: whether a ``CheckpointWriter`` was made since ``forget``, and the newest
    checkpoint one of them wrote (complete and verified on restart; None if none)."""
    return _record["writer"], _record["newest"]


class CheckpointWriter:
    """Operation writing checkpoints every ``every_steps`` steps and/or ``every_seconds`` seconds.

    payload: ``payload() -> (groups, series, attrs)`` of the current state (every rank).
    The seconds are measured on rank 0 and its decision is broadcast (every 10 steps), so all ranks
    write together. Keeps the newest ``keep`` files in ``directory`` (``step_<k>.h5``).
    """
    SECONDS_CHECK = 10   # steps between two looks at the clock

    def __init__(self, payload, directory, every_steps=0, every_seconds=0.0, keep=3, mode="auto",
                 start_step=0):
        self.payload, self.directory = payload, directory
        self.every_steps, self.every_seconds = int(every_steps), float(every_seconds)
        # the trigger: only the steps where a checkpoint may be due (an operation due on a step makes
        # that step compute its energies, so ``Periodic(1)`` would cost every step the energy sums)
        if self.every_seconds > 0:
            self.trigger = Periodic(math.gcd(self.every_steps, self.SECONDS_CHECK))
        else:
            self.trigger = Periodic(self.every_steps) if self.every_steps else Never()
        self.keep, self.mode = int(keep), mode
        self.last_time = time.monotonic()
        self.last_step = int(start_step)
        self.written = []
        _record["writer"] = True

    def __call__(self, sim):
        due = self.every_steps > 0 and sim.step_count % self.every_steps == 0
        if not due and self.every_seconds > 0 and sim.step_count % self.SECONDS_CHECK == 0:
            due = sim.comm.bcast(time.monotonic() - self.last_time >= self.every_seconds)
        if due:
            self.write(sim)

    def write(self, sim):
        """Write a checkpoint of the current step now (collective), unless one exists already.

        Raises InstabilityError (every rank) for a state holding a NaN or an infinity or a runaway
        speed (``Simulation.check_stability``), OutputError (every rank, ``all_ranks``; the
        ``.tmp`` removed, the earlier checkpoints kept) for an OS error."""
        if self.written and self.last_step == sim.step_count:
            return
        # never write (and keep) the state of a run that blew up: the collective check of every
        # evolving field here, and write_checkpoint refuses a NaN or infinity in the payload itself
        # (InstabilityError on every rank, nothing written)
        sim.check_stability()
        comm = sim.comm
        error = None
        if comm.is_root:
            try:
                os.makedirs(self.directory, exist_ok=True)
            except OSError as err:
                error = f"cannot create the checkpoint directory {self.directory}: {err.strerror or err}"
        error = comm.bcast(error)
        if error:
            err = OutputError(error)
            err.all_ranks = True       # raised on every rank: no abort needed (pardem.drivers.cli)
            raise err
        path = os.path.join(self.directory, checkpoint.checkpoint_name(sim.step_count))
        groups, series, attrs = self.payload()
        checkpoint.write_checkpoint(path, comm, groups, series, attrs, self.mode)
        self.written = [p for p in self.written if p != path] + [path]
        if comm.is_root:
            checkpoint.prune(self.written, self.keep)
        self.written = self.written[-self.keep:]
        _record["newest"] = path
        self.last_time = time.monotonic()
        self.last_step = sim.step_count
