"""``run_protocol``: the life of one restartable run, shared by the drivers.

A driver describes its protocol with a ``ProtocolDriver`` (deck schema, how to build the case, how
to restore it from a checkpoint, what one run executes, what its summary holds) and calls
``run_protocol`` (its ``main`` is ``protocol_main``); everything else is the same for every driver
and lives here, in this order:

1. the deck: ``--config``/``--set`` (on ``--restart``, the checkpoint's deck is the base), the
   protocol's checks, the restart policy (a restart may change only the keys the protocol lists);
2. the output folder checked (``cli.check_output``: path, lock, earlier results), then the case:
   ``build`` or ``restore``; bad input ends here with one line and exit 2, before any output exists;
3. the output folder taken (``cli.output_dir``), the protocol's series, the progress reporter, and the
   operations: the checkpoint writer (``[checkpoint]``, payload from the protocol), ParaView
   snapshots (``output.vtk_every``), the test fault injection (``PARDEM_FAULT``);
4. ``execute``: the protocol's run. ``--steps`` may stop it early (``StepLimit``: not an error); a
   stop signal ends it at a step boundary on every rank (``Interrupted``);
5. the final checkpoint (``checkpoint.at_end``; after a stop signal ``checkpoint.at_stop``), the
   summary JSON (common fields plus the protocol's), the plot, the printed result, the exit code
   (0, or ``EXIT_NOT_MEASURED`` when the run was too short to measure; an interrupted run exits
   128 + the signal number through ``cli.run_driver``).
"""
import contextlib
import os
import resource
import time
from dataclasses import dataclass, field

import pardem
from pardem.config import DeckError
from pardem.drivers import cli
from pardem.errors import DecompositionError, Interrupted
from pardem.engine.simulation import FaultInjection
from pardem.io import checkpoint, figures
from pardem.io.checkpoint_writer import CheckpointWriter
from pardem.io.paraview import ParaViewWriter
from pardem.io.progress import Progress
from pardem.io.summary import write_json
from pardem import restart
from pardem.parallel.communicator import Communicator
from pardem.protocols import granular_output as gout
from pardem.protocols.granular_output import StepLimit


@dataclass
class Run:
    """The state of one run, handed to the protocol's hooks."""
    comm: object
    args: object
    t_start: float
    meta: dict = None          # the checkpoint's attributes on --restart, else None
    deck: dict = None
    case: object = None
    out: str = ""
    progress: Progress = None
    operations: list = field(default_factory=list)
    writer: CheckpointWriter = None
    state: dict = field(default_factory=dict)   # the protocol's own state (kept in checkpoints)
    stopped: str = None        # why the run stopped early (--steps), or None
    interrupted: Interrupted = None
    files: contextlib.ExitStack = None
    series: object = None      # the protocol's series writer, if any

    @property
    def sim(self):
        return self.case.sim


class ProtocolDriver:
    """What a driver says about its protocol; ``run_protocol`` does the rest.

    Attributes: ``name`` (the driver's name: output folder ``runs/<name>-<stamp>``, summary
    ``<summary_name>``), ``schema`` (the deck), ``error_types`` (exceptions of build/restore that are
    bad input: one line, exit 2).
    """
    name = ""
    schema = None
    summary_name = "summary.json"
    error_types = ()

    def total_steps(self, run):
        """The run's total step count from its start, if known (the progress ETA), else None."""
        return None

    def paraview_trigger(self, run, every):
        """When the ParaView writer of ``output.vtk_every = every`` writes: ``(trigger, at_end)``
        (``Operation``). Default: every ``every`` steps only (the protocols run in many short
        ``sim.run``); a protocol of one ``sim.run`` may add its last step (``at_end``)."""
        return every, False

    def read_deck(self, run):
        """The checked deck (``run.meta`` holds the checkpoint's attributes on restart)."""
        return cli.read_deck(run.comm, self.schema, run.args, base=self.base_deck(run) if run.meta else None)

    def inspect(self, run):
        """The checkpoint's attributes (``checkpoint.inspect``); CheckpointError if unusable."""
        return checkpoint.inspect(run.args.restart, comm=run.comm)   # collective, verifies every byte

    def base_deck(self, run):
        return run.meta["deck"]

    def build(self, run):
        raise NotImplementedError

    def restore(self, run):
        raise NotImplementedError

    def payload(self, run):
        """``(groups, series, attrs)`` of a checkpoint of the current state."""
        raise NotImplementedError

    def start(self, run):
        """Open the series files (register closing with ``run.files``), print the header."""

    def execute(self, run):
        """The run itself (``run.operations`` to pass to every ``sim.run``)."""
        raise NotImplementedError

    def summary(self, run):
        """The protocol's fields of the summary (collective; rank 0's value is written)."""
        return {}

    def finish(self, run, summary):
        """Rank 0, after the summary is written: plots and the printed result; returns the exit
        code (``cli.EXIT_OK`` or ``cli.EXIT_NOT_MEASURED``)."""
        return cli.EXIT_OK


def protocol_main(driver_type, parser, argv=None):
    """A driver's ``main``: ``parser(comm)`` reads ``argv``, then ``run_protocol`` with a new
    ``driver_type()`` under ``cli.run_driver``; returns the exit code."""
    comm = Communicator()
    return cli.run_driver(comm, lambda comm, args: run_protocol(comm, args, driver_type()),
                          parser(comm).parse_args(argv))


def run_protocol(comm, args, protocol):
    """Run ``protocol`` (a ``ProtocolDriver``) for the parsed ``args``; returns the exit code."""
    with contextlib.ExitStack() as files:      # closes the series files whatever happens
        run = Run(comm=comm, args=args, t_start=time.perf_counter(), files=files)
        errors = (DeckError, checkpoint.CheckpointError, DecompositionError, *protocol.error_types)
        problem = fault = None
        try:
            if args.restart:
                run.meta = protocol.inspect(run)
            run.deck = protocol.read_deck(run)
            checkpoint.parallel_hdf5(run.deck["checkpoint"]["driver"])   # refuse "mpio" without MPI h5py now
            fault = FaultInjection.from_environment()     # a malformed PARDEM_FAULT is bad input
            checkpoint.checkpoint_pause()                 # ... and PARDEM_CHECKPOINT_PAUSE
        except errors as err:
            problem = str(err)
        cli.agree(comm, problem)      # one verdict on every rank before any collective build step
        out = cli.check_output(comm, args, protocol.name)   # a bad --out is refused before the build
        try:
            run.case = protocol.restore(run) if run.meta is not None else protocol.build(run)
        except errors as err:
            cli.fail_usage(comm, str(err))
        run.out = cli.output_dir(comm, args, protocol.name, out=out)   # checked again, created, locked
        deck, sim = run.deck, run.sim
        run.progress = Progress(comm, protocol.total_steps(run), deck["run"]["progress_seconds"],
                                int(comm.sum(sim.elements.n_owned)), quiet=args.quiet)
        protocol.start(run)
        ck = deck["checkpoint"]
        run.writer = CheckpointWriter(lambda: protocol.payload(run), os.path.join(run.out, "checkpoints"),
                                      ck["every_steps"], ck["every_seconds"], ck["keep"], ck["driver"],
                                      start_step=sim.step_count)
        run.operations = [run.writer]
        vtk_every = deck["output"]["vtk_every"]
        if vtk_every:
            trigger, at_end = protocol.paraview_trigger(run, vtk_every)
            # a restart's collections list the earlier run's snapshots up to the checkpoint
            earlier = cli.restarted_run(args.restart) if args.restart else None
            pv = ParaViewWriter(os.path.join(run.out, "paraview"), comm, trigger, at_end=at_end,
                                resume_step=sim.step_count if args.restart else None, dt=sim.dt,
                                previous=None if earlier is None else os.path.join(earlier, "paraview"))
            run.operations.append(pv)
            if sim.step_count == 0:
                pv(sim)    # the initial state
        if fault:
            run.operations.append(fault)
        try:
            protocol.execute(run)
        except StepLimit as err:
            run.stopped = str(err)
        except Interrupted as err:
            run.interrupted = err
            run.stopped = str(err)
        files.close()
        final = ck["at_stop"] if run.interrupted is not None else ck["at_end"]
        if final:
            run.writer.write(run.sim)
        result = protocol.summary(run)
        # the peak resident memory of every rank [MiB] (ru_maxrss: KiB on Linux; after a restart,
        # of the restarted run's processes only)
        rss = comm.allgather(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
        code = cli.EXIT_OK
        if comm.is_root:
            summary = _common_summary(run, protocol.name)
            summary["peak_rss_mib"] = rss
            summary.update(result)
            write_json(os.path.join(run.out, protocol.summary_name), summary)
            if run.interrupted is None:
                before = figures.png_times(run.out)
                code = protocol.finish(run, summary)
                if run.stopped is not None:   # a --steps stop: the figures it drew say so
                    figures.stamp_figures(run.out, before, figures.truncation_note(summary))
        if run.interrupted is not None:
            # cli.run_driver prints the one line (with the checkpoint to restart from) and exits
            # 128 + the signal number
            run.interrupted.checkpoint = run.writer.written[-1] if run.writer.written else None
            run.interrupted.final = bool(final)
            raise run.interrupted
        return comm.bcast(code)


def _common_summary(run, name):
    sim = run.sim
    return {"pardem_version": pardem.__version__, "driver": name, "n_ranks": run.comm.size,
            "steps": sim.step_count, "time": sim.time, "dt": sim.dt,
            "wall_seconds": time.perf_counter() - run.t_start,
            "finished": run.stopped is None, "stopped": run.stopped,
            "interrupted": (None if run.interrupted is None else
                            {"signal": run.interrupted.signum, "step": run.interrupted.step}),
            "restarted_from": run.args.restart, "checkpoints": run.writer.written, "deck": run.deck}


class GranularDriver(ProtocolDriver):
    """The granular drivers' common part: a checkpoint written by the same driver, the restart
    policy ``restart_may_change`` (keys besides [output] and [checkpoint]; ``restart_what`` words
    it for the message), ``pardem.engine.granular`` cases, the series ``<name>.csv``/``.h5`` of
    ``columns`` with ``units`` (rank 0; rows kept in the checkpoints), the protocol's ``run.state``."""
    restart_may_change = ()
    restart_what = ""
    columns = units = description = ()
    int_columns = ("step",)
    slab_axes = "xyz"

    def inspect(self, run):
        return gout.inspect_restart(run.args.restart, self.name, comm=run.comm)

    def read_deck(self, run):
        deck = super().read_deck(run)
        self.check(run, deck)
        if run.meta is not None:
            gout.check_restart(run.args.restart, run.meta, deck, self.schema, run.args.steps,
                               self.restart_may_change, self.restart_what)
        return deck

    def check(self, run, deck):
        """Protocol checks of the deck (DeckError) and command-line extras."""

    def restore(self, run):
        run.state = run.meta["protocol"]
        return restart.load_case(run.comm, run.args.restart, meta=run.meta,
                                 slab_axis=self.slab_axes.index(run.deck["run"]["slab_axis"]))

    def rows(self, run):
        """The series rows so far (from the checkpoint on restart)."""
        return gout.rows_of(run.meta["series"], self.columns, self.int_columns) if run.meta else []

    def open_series(self, run):
        run.series = gout.Series(run.comm, run.out, self.name, self.columns, self.units, self.description,
                                 self.rows(run), self.int_columns)
        run.files.callback(run.series.close)

    def payload(self, run):
        return gout.payload(run.case, run.deck, self.protocol_state(run), run.series.rows, self.columns)

    def protocol_state(self, run):
        return run.state
