"""Watchdog: no rank waits for ever on a rank that stopped answering.

Every rank runs a daemon thread that sends, once per ``period`` seconds, a slot of three numbers
to every other rank (non-blocking point-to-point on a duplicate of the run's communicator): its
tick count (the thread is alive, so the process runs), its heartbeat count (``beat()``, once per
time step) and its state. It takes the slots that arrived with ``Test`` (no collective, nothing
that waits on a silent rank) and aborts the job, with one line naming the rank(s), when

* an armed rank's ticks have not changed for ``timeout`` seconds: that process is stopped
  (SIGSTOP, a debugger), frozen, or lost;
* or no rank inside a time loop has beaten for ``timeout`` seconds although all tick: the ranks
  wait on each other (a deadlock), or one operation lasts longer than the watchdog allows.

A rank is armed from its first ``beat()`` (the time loop, ``Simulation.run``); once armed it also
expects signs of life from the ranks that have not reported a step yet. Before any rank's first
step (reading the deck, building the case) only signs of life are watched, with a limit of
``STARTUP_SECONDS`` (or the deck's, if longer): a long build may hold the GIL in one compiled call
(a packing, a Numba compilation) and stop its thread's ticks for a while, but a rank stopped or
lost during the build still ends the job.
``pause()`` (end of ``Simulation.run``) says this rank is not expected to beat until its next step;
``stop()`` that it is finished.

Why messages, not heartbeat files or a one-sided window: only this layer speaks MPI and only
``pardem.io`` opens files; messages need no shared file system (NFS caches mtimes for up to a
minute) and, unlike passive-target ``Get`` (which with MPICH over UCX waited on the target's
progress engine for 0.1-0.3 s and returned stale slots), a missing message is exactly the sign
of a silent rank and never blocks the reader.
The abort is ``MPI_Abort`` from the thread (mpi4py initialises MPICH at ``MPI_THREAD_MULTIPLE``);
mpiexec then ends every process, a stopped one included (SIGKILL), and ``os._exit`` follows if
the abort itself does not return within ``EXIT_FALLBACK_SECONDS``.
"""
import os
import sys
import threading
import time

import numpy as np

DEFAULT_SECONDS = 120.0
STARTUP_SECONDS = 600.0     # the limit on signs of life before any rank's first step [s]
EXIT_CODE = 1               # the drivers' "unexpected error: all ranks aborted"
EXIT_FALLBACK_SECONDS = 10.0
_TAG = 7
_WAITING, _ARMED, _PAUSED, _FINISHED = 0.0, 1.0, 2.0, 3.0

_beats = 0          # steps completed by this process (beat)
_paused_at = 0      # _beats at the last pause()
_current = None     # the running Watchdog of this process


def beat():
    """One unit of progress of this rank (one time step). A plain integer store: no MPI, no lock."""
    global _beats
    _beats += 1


def beats():
    """Heartbeats of this process so far (0 before its first time step)."""
    return _beats


def pause():
    """This rank left its time loop: not expected to beat until its next step (still watched for
    signs of life)."""
    global _paused_at
    _paused_at = _beats


def _state():
    if _beats == 0:
        return _WAITING
    return _ARMED if _beats > _paused_at else _PAUSED


class Watchdog:
    """The heartbeat messages and thread of one rank (``start`` makes it; collective)."""

    def __init__(self, comm, timeout=DEFAULT_SECONDS, report=None):
        from mpi4py import MPI
        self._MPI = MPI
        self.comm = comm
        self.timeout = float(timeout)
        self.report = report or (lambda line: (sys.stderr.write(line + "\n"), sys.stderr.flush()))
        self.wcomm = comm.comm.Dup()     # collective; the watchdog's messages never mix with the run's
        size, me = comm.size, comm.rank
        self._others = [r for r in range(size) if r != me]
        self._rbuf = np.zeros((size, 3))
        self._sbuf = np.zeros((size, 3))
        self._rreq = {r: self.wcomm.Irecv(self._rbuf[r], source=r, tag=_TAG) for r in self._others}
        self._sreq = {r: None for r in self._others}
        self._ticks = 0
        self._finished = False
        self._all_finished = threading.Event()
        self._halt = threading.Event()
        self._round_at = time.monotonic()
        self._publish()
        comm.barrier()                # every slot is initialised before anyone reads
        self._thread = threading.Thread(target=self._watch, name="pardem-watchdog", daemon=True)
        self._thread.start()

    @property
    def period(self):
        """Seconds between two rounds: a tenth of the timeout, within [0.05, 1]."""
        return min(1.0, max(0.05, self.timeout / 10.0)) if self.timeout > 0 else 1.0

    def _publish(self):
        """Send this rank's slot to every other rank whose previous message has left."""
        slot = (self._ticks, _beats, _FINISHED if self._finished else _state())
        for r in self._others:
            if self._sreq[r] is None or self._sreq[r].Test():
                self._sbuf[r] = slot
                self._sreq[r] = self.wcomm.Isend(self._sbuf[r], dest=r, tag=_TAG)

    def _read(self, r):
        """The newest slot received from rank ``r`` (None if nothing new)."""
        slot = None
        while self._rreq[r].Test():
            slot = self._rbuf[r].copy()
            self._rreq[r] = self.wcomm.Irecv(self._rbuf[r], source=r, tag=_TAG)
        return slot

    def _watch(self):
        size, me = self.comm.size, self.comm.rank
        seen = np.full((size, 2), -1.0)          # last (ticks, beats) read of each rank
        tick_at = np.full(size, time.monotonic())  # when each changed last (this rank's clock)
        beat_at = tick_at.copy()
        state = np.zeros(size)
        last, doomed_at = time.monotonic(), None
        while not self._halt.wait(self.period):
            now = time.monotonic()
            if now - last > max(3 * self.period, 2.0):
                # this thread itself could not run (GIL held, process stopped and resumed): it
                # observed nothing meanwhile, so nobody's silence counts from before now
                tick_at[:], beat_at[:] = now, now
            last = now
            self._ticks += 1
            self._publish()
            for r in range(size):
                if r == me or state[r] == _FINISHED:
                    continue
                slot = self._read(r)
                if slot is None:
                    continue
                if slot[0] != seen[r, 0]:
                    tick_at[r] = now
                if slot[1] != seen[r, 1]:
                    beat_at[r] = now
                seen[r], state[r] = slot[:2], slot[2]
            self._round_at = time.monotonic()
            if _beats != seen[me, 1]:
                beat_at[me] = now
            seen[me], state[me] = (self._ticks, _beats), (_FINISHED if self._finished else _state())
            if np.all(state == _FINISHED):
                self._close()
                self._all_finished.set()
                return
            line = self._verdict(now, tick_at, beat_at, state) if self.timeout > 0 else None
            if line is None:
                doomed_at = None
                continue
            silent_or_stalled, message = line
            # the lowest rank that still ticks reports; the others follow after a grace in case it
            # is gone too
            reporters = [r for r in range(size) if r not in silent_or_stalled[0] and state[r] != _FINISHED]
            if reporters and reporters[0] == me:
                self._abort(message)
            doomed_at = doomed_at or now
            if now - doomed_at > 3.0:
                self._abort(None)

    def _verdict(self, now, tick_at, beat_at, state):
        """None, or ((silent ranks, stalled ranks), message)."""
        me, t = self.comm.rank, self.timeout
        # once this rank runs its time loop, every unfinished rank must at least show signs of life
        # (one stopped before it could report its first step is silent too)
        armed = state[me] in (_ARMED, _PAUSED)
        started = armed or any(state[r] in (_ARMED, _PAUSED) for r in range(self.comm.size))
        limit = t if started else max(t, STARTUP_SECONDS)
        watched = [r for r in range(self.comm.size) if state[r] != _FINISHED]
        silent = [r for r in watched if r != me and now - tick_at[r] > limit]
        if silent:
            age = max(now - tick_at[r] for r in silent)
            when = "" if started else f" before the first time step (limit {limit:g} s while the case is built)"
            return (silent, []), (
                f"pardem: error: watchdog: {_ranks(silent)} silent for {age:.0f} s{when} (no sign of life: "
                f"process stopped, frozen or lost; limit run.watchdog_seconds = {t:g}); aborting all ranks")
        if any(r != me and now - tick_at[r] > max(3 * self.period, 2.0) for r in watched):
            return None     # a rank is falling silent: its verdict follows, it explains the stall
        looping = [r for r in range(self.comm.size) if state[r] == _ARMED]
        if looping and all(now - beat_at[r] > t for r in looping):
            age = min(now - beat_at[r] for r in looping)
            done = [r for r in range(self.comm.size) if state[r] == _FINISHED]
            return ([], looping), (
                f"pardem: error: watchdog: no progress on {_ranks(looping)} for {age:.0f} s although every rank "
                f"is alive (ranks waiting on each other, or one operation longer than run.watchdog_seconds "
                f"= {t:g})" + (f"; finished: {_ranks(done)}" if done else "") + "; aborting all ranks")
        return None

    def _abort(self, message):
        if message:
            self.report(message)
        threading.Timer(EXIT_FALLBACK_SECONDS, os._exit, (EXIT_CODE,)).start()
        self.comm.abort(EXIT_CODE)

    def stop(self):
        """This rank is finished: say so in its slot, wait (still watching) until every rank is,
        then end the messages and free the watchdog's communicator (MPICH over UCX asserts at
        ``MPI_Finalize`` on MPI objects left in use)."""
        if self._finished:
            return
        self._finished = True
        self._all_finished.wait()
        self._halt.set()
        self._thread.join()

    def _close(self):
        """Every rank is finished: end the watchdog's messages and free its communicator."""
        self._MPI.Request.Waitall([q for q in self._sreq.values() if q is not None])
        self.wcomm.Barrier()      # nobody sends after this (each saw every rank finished)
        for r in self._others:
            while self._read(r) is not None:   # messages sent before the barrier
                pass
            self._rreq[r].Cancel()
            self._rreq[r].Wait()
        self.wcomm.Free()


def _ranks(ranks):
    return ("rank " if len(ranks) == 1 else "ranks ") + ", ".join(str(r) for r in ranks)


def start(comm, timeout=DEFAULT_SECONDS):
    """Collective: start this process's watchdog (None on one rank: nobody can wait on another).
    ``timeout`` [s] without progress; 0 watches nothing until ``configure`` sets a limit."""
    global _current
    if comm.size == 1 or _current is not None:
        return _current
    _current = Watchdog(comm, timeout)
    return _current


def configure(timeout):
    """Set the limit [s] of the running watchdog (the deck's ``run.watchdog_seconds``; 0 = off).
    Local: every rank reads the same deck."""
    if timeout < 0:
        raise ValueError(f"watchdog timeout {timeout}: expected >= 0")
    if _current is not None:
        _current.timeout = float(timeout)


def stop():
    """This rank is finished: its slot says so; returns when every rank is (then the watchdog's
    messages end). Called by every rank at the end of ``cli.run_driver``."""
    global _current
    if _current is not None:
        _current.stop()
        _current = None
