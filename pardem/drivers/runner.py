"""``run_protocol``: the life of one run, shared by every driver.

A driver describes its protocol with a ``ProtocolDriver`` (deck schema, how to build the case, how
to restore it, what the run executes, what its summary holds) and calls ``run_protocol`` (its
``main`` is ``protocol_main``); everything else is the same for every driver and lives here, in
this order:

1. the deck: ``--config``/``--set`` (on ``--restart``, the checkpoint's deck is the base), the
   protocol's checks, the restart policy (a restart may change only the keys the protocol lists);
2. the output folder checked (``cli.check_output``: path, lock, earlier results), then the case:
   ``build`` or ``restore``; bad input ends here with one line and exit 2, before any output exists;
3. the output folder taken (``cli.output_dir``), then ``setup``: the progress reporter, the
   protocol's series (``start``), and the operations: the checkpoint writer (``[checkpoint]``,
   payload from the protocol), ParaView snapshots (``output.vtk_every``), the test fault
   injection (``PARDEM_FAULT``);
4. ``execute``: the protocol's run. ``--steps`` may stop it early (``StepLimit``: not an error); a
   stop signal ends it at a step boundary on every rank (``Interrupted``);
5. the final checkpoint (``checkpoint.at_end``; after a stop signal ``checkpoint.at_stop``), the
   summary JSON (common fields plus the protocol's), the plot, the printed result, the exit code
   (0, or ``EXIT_NOT_MEASURED`` when the run was too short to measure; an interrupted run exits
   128 + the signal number through ``cli.run_driver``).

A study of many cases (``StudyDriver``: realisations or parameter points, spread over the ranks by
``pardem.parallel.task_farm`` or run one after the other) has the same life without the parts of
one simulation: its ``execute`` runs the cases, each with its own outputs and record
(``DIR/records``, what ``--restart DIR`` continues from), and its summary's common fields are those
that belong to no one simulation.
"""
import contextlib
import os
import resource
import time
from dataclasses import dataclass, field

import pardem
from pardem.config import DeckError
from pardem.drivers import cli
from pardem.errors import DecompositionError, Interrupted, StepLimit
from pardem.engine.simulation import FaultInjection
from pardem.io import checkpoint, figures
from pardem.io.checkpoint_writer import CheckpointWriter
from pardem.io.paraview import ParaViewWriter
from pardem.io.progress import Progress
from pardem.io.summary import write_json
from pardem.parallel.communicator import Communicator


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
    fault: FaultInjection = None   # PARDEM_FAULT's operation, if any

    @property
    def sim(self):
        return self.case.sim


class ProtocolDriver:
    """What a driver says about its protocol; ``run_protocol`` does the rest.

    Attributes: ``name`` (the driver's name: output folder ``runs/<name>-<stamp>``, summary
    ``<summary_name>``), ``schema`` (the deck), ``error_types`` (exceptions of build/restore that are
    bad input: one line, exit 2), ``common_key`` (where the summary's common fields go: None at its
    top level, else under this key, beside the protocol's own fields there), ``stops_together``
    (a stop signal reaches every rank at the same step: True for one simulation).

    The defaults are those of one restartable simulation (``run.case.sim``); ``StudyDriver`` holds
    those of a study of many cases.
    """
    name = ""
    schema = None
    summary_name = "summary.json"
    error_types = ()
    common_key = None
    stops_together = True

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

    def check_environment(self, run):
        """Bad input outside the deck, judged with it (one verdict on every rank): the checkpoint
        driver (``"mpio"`` needs an MPI h5py), ``PARDEM_FAULT``, ``PARDEM_CHECKPOINT_PAUSE``."""
        checkpoint.parallel_hdf5(run.deck["checkpoint"]["driver"])
        run.fault = FaultInjection.from_environment()
        checkpoint.checkpoint_pause()

    def build(self, run):
        raise NotImplementedError

    def restore(self, run):
        raise NotImplementedError

    def payload(self, run):
        """``(groups, series, attrs)`` of a checkpoint of the current state."""
        raise NotImplementedError

    def setup(self, run):
        """After the output folder is taken: the progress reporter, ``start``, and the operations
        of every ``sim.run`` (``run.operations``): the checkpoint writer, the ParaView writer
        (``output.vtk_every``, the initial state at step 0), the fault injection."""
        comm, deck, sim, args = run.comm, run.deck, run.sim, run.args
        run.progress = Progress(comm, self.total_steps(run), deck["run"]["progress_seconds"],
                                int(comm.sum(sim.elements.n_owned)), quiet=args.quiet)
        self.start(run)
        ck = deck["checkpoint"]
        run.writer = CheckpointWriter(lambda: self.payload(run), os.path.join(run.out, "checkpoints"),
                                      ck["every_steps"], ck["every_seconds"], ck["keep"], ck["driver"],
                                      start_step=sim.step_count)
        run.operations = [run.writer]
        vtk_every = deck["output"]["vtk_every"]
        if vtk_every:
            trigger, at_end = self.paraview_trigger(run, vtk_every)
            # a restart's collections list the earlier run's snapshots up to the checkpoint
            earlier = cli.restarted_run(args.restart) if args.restart else None
            pv = ParaViewWriter(os.path.join(run.out, "paraview"), comm, trigger, at_end=at_end,
                                resume_step=sim.step_count if args.restart else None, dt=sim.dt,
                                previous=None if earlier is None else os.path.join(earlier, "paraview"))
            run.operations.append(pv)
            if sim.step_count == 0:
                pv(sim)    # the initial state
        if run.fault:
            run.operations.append(run.fault)

    def start(self, run):
        """Open the series files (register closing with ``run.files``), print the header."""

    def execute(self, run):
        """The run itself (``run.operations`` to pass to every ``sim.run``)."""
        raise NotImplementedError

    def final_checkpoint(self, run):
        """After ``execute``: the final checkpoint (``checkpoint.at_end``; after a stop signal
        ``checkpoint.at_stop``); returns whether it was written."""
        ck = run.deck["checkpoint"]
        final = ck["at_stop"] if run.interrupted is not None else ck["at_end"]
        if final:
            run.writer.write(run.sim)
        return bool(final)

    def interrupted(self, run, err, final):
        """Tell ``err`` where to restart from (``cli.interrupted_line`` words it)."""
        err.checkpoint = run.writer.written[-1] if run.writer.written else None
        err.final = final

    def summary(self, run):
        """The protocol's fields of the summary (collective; rank 0's value is written)."""
        return {}

    def common_summary(self, run):
        """The summary's common fields (rank 0): those of every driver plus the simulation's."""
        sim = run.sim
        return _common_fields(run, self.name, {"steps": sim.step_count, "time": sim.time, "dt": sim.dt},
                              {"checkpoints": run.writer.written})

    def finish(self, run, summary):
        """Rank 0, after the summary is written: plots and the printed result; returns the exit
        code (``cli.EXIT_OK`` or ``cli.EXIT_NOT_MEASURED``)."""
        return cli.EXIT_OK


class StudyDriver(ProtocolDriver):
    """A study of many cases (realisations, parameter points: a task farm over the ranks, or one
    case after the other on every rank), each with its own outputs and record: no one simulation,
    so no progress reporter, checkpoint or ParaView writer of the runner's; ``execute`` runs the
    cases. ``--restart DIR`` names an earlier study's output folder, whose records the study reads
    with its deck (``read_deck``: ``cli.study_restart`` checks the header, so another deck or plan
    is refused before the output folder); ``inspect`` may read the header first (the base deck). A stop
    signal ends the study with the records written so far (each case's rank stops at its own
    step, so no collective summary follows), from which ``--restart`` continues. The summary's
    common fields go under ``meta`` unless ``common_key`` says otherwise."""
    common_key = "meta"
    stops_together = False

    def inspect(self, run):
        return {}

    def base_deck(self, run):
        return None

    def check_environment(self, run):
        pass

    def restore(self, run):
        return self.build(run)

    def setup(self, run):
        self.start(run)

    def final_checkpoint(self, run):
        return False

    def interrupted(self, run, err, final):
        err.records = run.out

    def common_summary(self, run):
        return _common_fields(run, self.name)


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
        problem = None
        try:
            if args.restart:
                run.meta = protocol.inspect(run)
            run.deck = protocol.read_deck(run)
            protocol.check_environment(run)
        except errors as err:
            problem = str(err)
        cli.agree(comm, problem)      # one verdict on every rank before any collective build step
        out = cli.check_output(comm, args, protocol.name)   # a bad --out is refused before the build
        try:
            run.case = protocol.restore(run) if run.meta is not None else protocol.build(run)
        except errors as err:
            cli.fail_usage(comm, str(err))
        run.out = cli.output_dir(comm, args, protocol.name, out=out)   # checked again, created, locked
        protocol.setup(run)
        try:
            protocol.execute(run)
        except StepLimit as err:
            run.stopped = str(err)
        except Interrupted as err:
            run.interrupted = err
            run.stopped = str(err)
        files.close()
        final = protocol.final_checkpoint(run)
        if run.interrupted is not None and not protocol.stops_together:
            protocol.interrupted(run, run.interrupted, final)
            raise run.interrupted
        result = protocol.summary(run)
        # the peak resident memory of every rank [MiB] (ru_maxrss: KiB on Linux; after a restart,
        # of the restarted run's processes only)
        rss = comm.allgather(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
        code = cli.EXIT_OK
        if comm.is_root:
            common = protocol.common_summary(run)
            common["peak_rss_mib"] = rss
            if protocol.common_key is None:
                summary = {**common, **result}
            else:
                summary = dict(result)
                summary[protocol.common_key] = {**common, **result.get(protocol.common_key, {})}
            write_json(os.path.join(run.out, protocol.summary_name), summary)
            if run.interrupted is None:
                before = figures.png_times(run.out)
                code = protocol.finish(run, summary)
                if run.stopped is not None:   # a --steps stop: the figures it drew say so
                    figures.stamp_figures(run.out, before, figures.truncation_note(summary))
        if run.interrupted is not None:
            # cli.run_driver prints the one line (with the checkpoint to restart from) and exits
            # 128 + the signal number
            protocol.interrupted(run, run.interrupted, final)
            raise run.interrupted
        return comm.bcast(code)


def _common_fields(run, name, clock=None, written=None):
    """The summary fields of every driver (rank 0); a simulation's ``clock`` (steps, time, dt) and
    ``written`` (its checkpoints) in their places."""
    return {"pardem_version": pardem.__version__, "driver": name, "n_ranks": run.comm.size, **(clock or {}),
            "wall_seconds": time.perf_counter() - run.t_start,
            "finished": run.stopped is None, "stopped": run.stopped,
            "interrupted": (None if run.interrupted is None else
                            {"signal": run.interrupted.signum, "step": run.interrupted.step}),
            "restarted_from": run.args.restart, **(written or {}), "deck": run.deck}
