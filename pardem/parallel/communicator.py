"""MPI communicator wrapper: collectives used by the engine, and all-ranks abort on failure.

Everything above this layer calls these verbs and never mpi4py directly, so a run on one process
without ``mpiexec`` works the same way (MPI singleton).

Every blocking verb on more than one rank (the collectives and ``waitall``) marks this process as
inside it in ``watchdog.COLLECTIVE`` (its name, and a call count that is odd while inside: two
integer increments and one store per call), and the first ``Communicator`` of ``COMM_WORLD`` on
several ranks starts the script watchdog (``watchdog.protect_script``): a collective entered by
some ranks only ends the job with one line naming it and where every rank is.
"""
import os
import sys
import threading
import time
import traceback

import numpy as np

from pardem.parallel import watchdog

ABORT_GRACE_SECONDS = 1.0
FOLLOW_SECONDS = 5.0       # exit_now: another rank ends the job this long after a signal rank 0 did not act on
IDLE_POLL_SECONDS = 0.05    # wait_for_all's sleep between polls: 50 ms late at most, for cases of minutes


_AT = watchdog.COLLECTIVE      # this process's collective in progress (read by the watchdog thread)


class Communicator:
    """Thin wrapper over an mpi4py communicator (default ``COMM_WORLD``)."""

    def __init__(self, comm=None):
        from mpi4py import MPI
        self._MPI = MPI
        self.comm = MPI.COMM_WORLD if comm is None else comm
        self.rank = self.comm.Get_rank()
        self.size = self.comm.Get_size()
        if self.size > 1 and self.comm == MPI.COMM_WORLD:
            watchdog.protect_script(self)

    @property
    def is_root(self) -> bool:
        return self.rank == 0

    def sum(self, values):
        """Element-wise sum over ranks of a float64 array (or scalar); same result on every rank."""
        return self._allreduce(values, self._MPI.SUM, "Communicator.sum")

    def max_array(self, values):
        """Element-wise maximum over ranks of a float64 array; same result on every rank."""
        return self._allreduce(values, self._MPI.MAX, "Communicator.max_array")

    def _allreduce(self, values, op, name):
        a = np.array(values, dtype=np.float64)   # a copy, C-contiguous, 0-d for a scalar
        if self.size == 1:
            return a
        out = np.empty_like(a)
        at = _AT
        at.name = name
        at.calls += 1
        try:
            self.comm.Allreduce(a, out, op=op)
        finally:
            at.calls += 1
        return out

    def _collective(self, name, call, *args, **kwargs):
        """``call(*args, **kwargs)`` marked in ``watchdog.COLLECTIVE`` as this rank's collective ``name``."""
        at = _AT
        at.name = name
        at.calls += 1
        try:
            return call(*args, **kwargs)
        finally:
            at.calls += 1

    def min(self, value):
        if self.size == 1:
            return value
        return self._collective("Communicator.min", self.comm.allreduce, value, op=self._MPI.MIN)

    def max(self, value):
        if self.size == 1:
            return value
        return self._collective("Communicator.max", self.comm.allreduce, value, op=self._MPI.MAX)

    def any(self, flag: bool) -> bool:
        if self.size == 1:
            return bool(flag)
        return bool(self._collective("Communicator.any", self.comm.allreduce, bool(flag), op=self._MPI.LOR))

    def allgather(self, obj):
        """List of every rank's ``obj`` (pickled; for small metadata)."""
        return self._collective("Communicator.allgather", self.comm.allgather, obj) if self.size > 1 else [obj]

    def allgatherv(self, values):
        """Every rank's rows of ``values`` (a float64 or int64 array [n_rank, ...], the trailing
        shape the same on every rank, n_rank may be 0) concatenated in rank order: [sum n_rank,
        ...], the same on every rank (``MPI_Allgatherv``, no pickling)."""
        a = np.ascontiguousarray(values)
        if a.dtype not in (np.float64, np.int64) or a.ndim < 1:
            raise TypeError(f"allgatherv: values of dtype {a.dtype} and {a.ndim} dimensions; expected a float64 "
                            "or int64 array with a first (row) axis")
        if self.size == 1:
            return a.copy()
        return self._collective("Communicator.allgatherv", self._allgatherv, a)

    def _allgatherv(self, a):
        tail = a.shape[1:]
        width = int(np.prod(tail, dtype=np.int64))
        meta = np.empty((self.size, 2 + len(tail)), dtype=np.int64)
        self.comm.Allgather(np.array([a.shape[0], a.dtype == np.int64, *tail], dtype=np.int64), meta)
        if np.any(meta[:, 1:] != meta[0, 1:]):
            raise ValueError(f"allgatherv: ranks differ in dtype or trailing shape: {meta[:, 1:].tolist()}")
        items = meta[:, 0] * width
        displs = np.concatenate([[0], np.cumsum(items)[:-1]])
        out = np.empty((int(meta[:, 0].sum()),) + tail, dtype=a.dtype)
        kind = self._MPI.INT64_T if a.dtype == np.int64 else self._MPI.DOUBLE
        self.comm.Allgatherv([a, kind], [out, (items.tolist(), displs.tolist()), kind])
        return out

    def gather(self, obj, root=0):
        """List of every rank's ``obj`` on ``root`` (None elsewhere)."""
        return self._collective("Communicator.gather", self.comm.gather, obj, root=root) if self.size > 1 else [obj]

    def bcast(self, obj, root=0):
        return self._collective("Communicator.bcast", self.comm.bcast, obj, root=root) if self.size > 1 else obj

    def waitall(self, requests):
        """Complete non-blocking point-to-point requests (``Isend``/``Irecv`` of ``self.comm``)."""
        if self.size == 1:
            self._MPI.Request.Waitall(requests)
            return
        # not a collective, but it waits on the neighbours' matching calls all the same (the halo
        # exchange of every step: marked inline, the cheapest form)
        at = _AT
        at.name = "Communicator.waitall"
        at.calls += 1
        try:
            self._MPI.Request.Waitall(requests)
        finally:
            at.calls += 1

    def split_self(self):
        """A communicator of this rank alone (independent cases of a task farm)."""
        return Communicator(self._MPI.COMM_SELF)

    def barrier(self):
        if self.size > 1:
            self._collective("Communicator.barrier", self.comm.Barrier)

    def wait_for_all(self, poll_seconds=IDLE_POLL_SECONDS):
        """Collective: return once every rank has called it, sleeping between ``Test`` polls of an
        ``Ibarrier``, so a rank that finished its cases early uses no core: MPICH's blocking
        collectives busy-poll (a waiting ``Barrier``, or the root of a ``Gather``, used a whole core).

        Call it right before a collective that idle ranks would otherwise wait in. A rank that fails
        meanwhile ends the job through ``abort`` (``MPI_Abort``), which kills the waiting ranks too."""
        if self.size == 1:
            return
        self._collective("Communicator.wait_for_all", self._idle_barrier, poll_seconds)

    def _idle_barrier(self, poll_seconds):
        request = self.comm.Ibarrier()
        while not request.Test():
            time.sleep(poll_seconds)

    def started_by_srun(self):
        """Collective: True if Slurm's ``srun`` started every rank itself (one Slurm task per rank,
        ``srun --mpi=pmi2`` or ``pmix``), False under ``mpiexec`` (also inside a Slurm job).

        srun reports the ranks' own exit codes, so ranks that all stop together may simply exit;
        under srun an ``MPI_Abort`` is reported as "Killed" (137), and in a step that Slurm is
        already cancelling it does nothing until Slurm's SIGKILL (``KillWait``, 30 s)."""
        mine = srun_task(self.rank, self.size)
        if self.size == 1:
            return mine
        return bool(self._collective("Communicator.started_by_srun", self.comm.allreduce, mine, op=self._MPI.LAND))

    def abort(self, code=1):
        """End every rank of the job now (used when one rank fails and the others may be waiting).

        Flushes, then waits a moment so that the MPI launcher forwards this rank's last output
        before it tears the job down.
        """
        sys.stdout.flush()
        sys.stderr.flush()
        time.sleep(ABORT_GRACE_SECONDS)
        self.comm.Abort(code)


def srun_task(rank, size):
    """This process is Slurm task ``rank`` of a step of ``size`` tasks with Slurm's own PMI, i.e.
    srun started the MPI ranks (under mpiexec inside a Slurm job the tasks are hydra's proxies,
    one per node, and the ranks see hydra's PMI without ``PMI_JOBID``)."""
    env = os.environ
    return (env.get("SLURM_PROCID") == str(rank) and env.get("SLURM_STEP_NUM_TASKS") == str(size)
            and ("PMI_JOBID" in env or "PMIX_RANK" in env))


def exit_now(code, rank, message):
    """End the job with ``code`` from a signal handler every rank received (no Python clean-up,
    no exception raised); ``pardem: <message>`` goes to stderr from the rank that ends it (with
    ``rank R:`` when it is not rank 0).

    With MPI: rank 0 writes the line and calls ``MPI_Abort`` at once; ``os._exit`` alone is not
    enough (mpiexec.mpich reported such a job, after forwarding the signal, as exit code 0 in 2 of
    3 tries) and ``MPI_Finalize`` in a handler can wait for ever. Another rank returns at once and
    leaves a thread that ends the job ``FOLLOW_SECONDS`` later (its line naming the rank) if
    rank 0 has not: its main thread must go on, since rank 0 may be inside a collective waiting for
    it and could not run its own handler before that collective ends (a handler that slept there
    aborted the job before rank 0 wrote its line). Under srun every task is signalled and srun
    reports the tasks' own exit codes: each task leaves with ``code``.
    """
    from mpi4py import MPI
    size = MPI.COMM_WORLD.Get_size() if MPI.Is_initialized() and not MPI.Is_finalized() else 1
    if size > 1 and not srun_task(rank, size):
        if rank != 0:
            threading.Thread(target=_follow, args=(code, f"pardem: rank {rank}: {message}"),
                             name="pardem-exit", daemon=True).start()
            return
        _write_line(f"pardem: {message}")
        MPI.COMM_WORLD.Abort(code)
    if rank == 0:
        _write_line(f"pardem: {message}")
    os._exit(code)


def _write_line(line):
    sys.stdout.flush()
    sys.stderr.flush()
    os.write(2, f"{line}\n".encode())


def _follow(code, line):
    """Rank 0 did not end the job within ``FOLLOW_SECONDS`` (it was not signalled, or is stuck):
    this rank ends it."""
    from mpi4py import MPI
    time.sleep(FOLLOW_SECONDS)
    _write_line(line)
    MPI.COMM_WORLD.Abort(code)


def report_and_abort(comm, exc, code=1):
    """Print an unexpected exception of this rank once, then abort all ranks (never hangs)."""
    sys.stderr.write(f"pardem: rank {comm.rank}: unexpected error:\n")
    traceback.print_exception(exc, file=sys.stderr)
    if comm.size > 1:
        comm.abort(code)
    raise SystemExit(code)
