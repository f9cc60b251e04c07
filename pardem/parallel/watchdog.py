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

Scripts (``protect_script``): a user's script run under ``mpiexec -n N`` is watched without doing
anything. The first ``Communicator`` of ``COMM_WORLD`` on more than one rank starts this watchdog
(its duplicate communicator by ``MPI_Comm_idup``, completed by the thread, so a constructor called
on some ranks only does not block), stopped at interpreter exit (``atexit``, before
``MPI_Finalize``; a rank that reached the end waits there for the others, still watching); a
driver's ``start`` takes it over with the driver's semantics. On top of the checks above it
watches the collectives: every blocking verb of ``Communicator`` (sum, max_array, min, max, any,
allgather, allgatherv, gather, bcast, barrier, wait_for_all, started_by_srun, and the point-to-point
``waitall``) marks this process as inside it in ``COLLECTIVE`` (a call count, odd while inside,
and the verb's name: two integer increments and one store), and every slot also carries that
count and, in text, where the rank is (the collective and its callers in pardem and in the script,
or the line it runs outside any collective, from a sample of the main thread's stack taken by the
watchdog thread once per round, nothing on the calling side). When one rank has stayed in the same
collective call for the limit while another rank is not in that collective (``wait_for_all``
excepted: a task farm's rank done early waits there by design), the job is aborted with one line (from one rank) naming the collective, its callers and
what every other rank does, e.g.

    pardem: error: watchdog: rank 0 has waited 120 s in Communicator.sum called from
    pardem/parallel/exact_sum.py:23 (total) <- pardem/engine/simulation.py:303
    (Simulation.kinetic_energy) <- script.py:17; rank 1 is outside any collective, at script.py:20
    (a collective called on some ranks only? limit 120 s, set by PARDEM_WATCHDOG_SECONDS or
    pardem.parallel.watchdog.configure, 0 = off); aborting all ranks

(one line; a rank in another collective is named with its own, one that reached the end of the
script as waiting at its exit). The limit is ``DEFAULT_SECONDS`` (120 s); ``PARDEM_WATCHDOG_SECONDS=S`` in the
environment or ``configure(S)`` in the script sets it, 0 switches the script watchdog off (the
variable, read when the first ``Communicator`` is made: then nothing starts). A rank legitimately
outside any collective for longer than the limit while another waits in one (rank 0 plotting for
minutes while the others wait in a barrier) cannot be told from a rank that skipped the
collective: raise the limit for such scripts. On one rank nothing starts.
"""
import atexit
import os
import sys
import sysconfig
import threading
import time

import numpy as np

DEFAULT_SECONDS = 120.0
STARTUP_SECONDS = 600.0     # the limit on signs of life before any rank's first step [s]
EXIT_CODE = 1               # the drivers' "unexpected error: all ranks aborted"
EXIT_FALLBACK_SECONDS = 10.0
ENV = "PARDEM_WATCHDOG_SECONDS"   # the script watchdog's limit [s] (0 = off)
_TAG = 7
_WAITING, _ARMED, _PAUSED, _FINISHED = 0.0, 1.0, 2.0, 3.0
_HEAD = 5               # a slot: ticks, beats, state, collective calls, idle wait, then WHERE_BYTES of text
IDLE_WAIT = "Communicator.wait_for_all"   # a wait that may last (a task farm's rank done early)
WHERE_BYTES = 480       # where the rank is (UTF-8, cut)

_beats = 0          # steps completed by this process (beat)
_paused_at = 0      # _beats at the last pause()
_current = None     # the running Watchdog of this process
_script_seconds = None  # configure()'s limit for a script watchdog not started yet
_protected = False  # protect_script ran (a script watchdog starts at most once per process)


class _Collective:
    """This process's blocking ``Communicator`` call: ``calls`` counts entries and exits (odd while
    inside one), ``name`` is the last one entered. Written by the calling thread, read by the
    watchdog thread (single attribute reads and writes under the GIL)."""
    __slots__ = ("calls", "name")

    def __init__(self):
        self.calls, self.name = 0, ""


COLLECTIVE = _Collective()


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

    def __init__(self, comm, timeout=DEFAULT_SECONDS, report=None, script=False):
        from mpi4py import MPI
        self._MPI = MPI
        self.comm = comm
        self.timeout = float(timeout)
        self.script = script      # also watch the collectives (a script's watchdog, see protect_script)
        self.report = report or (lambda line: (sys.stderr.write(line + "\n"), sys.stderr.flush()))
        size, me = comm.size, comm.rank
        self._others = [r for r in range(size) if r != me]
        self._rbuf = np.zeros((size, _HEAD + WHERE_BYTES // 8))
        self._sbuf = np.zeros((size, _HEAD + WHERE_BYTES // 8))
        self._sreq = {r: None for r in self._others}
        self._ticks = 0
        self._finished = False
        self._all_finished = threading.Event()
        self._halt = threading.Event()
        self._round_at = time.monotonic()
        self._main = threading.main_thread().ident
        if script:
            # non-blocking: a Communicator made on some ranks only must not hang in its constructor
            self.wcomm, dup = comm.comm.Idup()
        else:
            self.wcomm, dup = comm.comm.Dup(), None   # collective; the watchdog's messages never mix with the run's
            self._begin()
            comm.barrier()                # every slot is initialised before anyone reads
        self._thread = threading.Thread(target=self._watch, args=(dup,), name="pardem-watchdog", daemon=True)
        self._thread.start()

    def _begin(self):
        self._rreq = {r: self.wcomm.Irecv(self._rbuf[r], source=r, tag=_TAG) for r in self._others}
        self._publish()

    @property
    def period(self):
        """Seconds between two rounds: a tenth of the timeout, within [0.05, 1]."""
        return min(1.0, max(0.05, self.timeout / 10.0)) if self.timeout > 0 else 1.0

    def _mine(self):
        """This rank's slot [_HEAD + WHERE_BYTES / 8] (the call count and the stack are read together:
        the main thread cannot run Python code meanwhile, this thread holds the GIL)."""
        slot = np.zeros(self._sbuf.shape[1])
        calls = COLLECTIVE.calls
        idle = calls % 2 == 1 and COLLECTIVE.name == IDLE_WAIT
        slot[:_HEAD] = (self._ticks, _beats, _FINISHED if self._finished else _state(), calls, idle)
        text = where(sys._current_frames().get(self._main), calls).encode()[:WHERE_BYTES]
        slot.view(np.uint8)[8 * _HEAD:8 * _HEAD + len(text)] = np.frombuffer(text, np.uint8)
        return slot

    def _publish(self):
        """Send this rank's slot to every other rank whose previous message has left."""
        slot = self._mine()
        for r in self._others:
            if self._sreq[r] is None or self._sreq[r].Test():
                self._sbuf[r] = slot
                self._sreq[r] = self.wcomm.Isend(self._sbuf[r], dest=r, tag=_TAG)
        return slot

    def _read(self, r):
        """The newest slot received from rank ``r`` (None if nothing new)."""
        slot = None
        while self._rreq[r].Test():
            slot = self._rbuf[r].copy()
            self._rreq[r] = self.wcomm.Irecv(self._rbuf[r], source=r, tag=_TAG)
        return slot

    def _watch(self, dup):
        if dup is not None:
            while not dup.Test():          # every rank made its first Communicator
                if self._halt.wait(0.05):
                    return
            self._begin()
        size, me = self.comm.size, self.comm.rank
        seen = np.full((size, 3), -1.0)          # last (ticks, beats, collective calls) read of each rank
        tick_at = np.full(size, time.monotonic())  # when each changed last (this rank's clock)
        beat_at = tick_at.copy()
        calls_at = tick_at.copy()
        state = np.zeros(size)
        idle = np.zeros(size, dtype=bool)       # in wait_for_all at its last slot
        self._where = [""] * size               # where each rank was at its last slot
        last, doomed_at = time.monotonic(), None
        while not self._halt.wait(self.period):
            now = time.monotonic()
            if now - last > max(3 * self.period, 2.0):
                # this thread itself could not run (GIL held, process stopped and resumed): it
                # observed nothing meanwhile, so nobody's silence counts from before now
                tick_at[:], beat_at[:], calls_at[:] = now, now, now
            last = now
            self._ticks += 1
            mine = self._publish()
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
                if slot[3] != seen[r, 2]:
                    calls_at[r] = now
                seen[r], state[r], idle[r] = slot[[0, 1, 3]], slot[2], slot[4]
                self._where[r] = _text(slot)
            self._round_at = time.monotonic()
            if _beats != seen[me, 1]:
                beat_at[me] = now
            if mine[3] != seen[me, 2]:
                calls_at[me] = now
            seen[me], state[me], idle[me] = mine[[0, 1, 3]], mine[2], mine[4]
            self._where[me] = _text(mine)
            if np.all(state == _FINISHED):
                self._close()
                self._all_finished.set()
                return
            line = (self._verdict(now, tick_at, beat_at, state, seen[:, 2], calls_at, idle)
                    if self.timeout > 0 else None)
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

    def _verdict(self, now, tick_at, beat_at, state, calls=None, calls_at=None, idle=None):
        """None, or ((silent ranks, stalled ranks), message). ``calls`` [size]: each rank's
        collective call count, ``calls_at`` [size] when it last changed (this rank's clock),
        ``idle`` [size] whether that call is ``wait_for_all`` (not stalled however long it lasts)."""
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
                f"process stopped, frozen or lost; limit {self._limit_name} = {t:g}); aborting all ranks")
        if any(r != me and now - tick_at[r] > max(3 * self.period, 2.0) for r in watched):
            return None     # a rank is falling silent: its verdict follows, it explains the stall
        if self.script and calls is not None:
            inside = [r for r in watched if calls[r] % 2 == 1]
            # every rank in the same verb is a long collective, not ranks waiting for each other
            # (a silent rank has its own verdict above)
            together = len(inside) == self.comm.size and len({self._where[r].split(" ")[0] for r in inside}) == 1
            if not together and any(now - calls_at[r] > t and not idle[r] for r in inside):
                return ([], inside), self._stuck_message(now, state, calls, calls_at)
            if any(not idle[r] for r in inside):
                return None     # a rank waits in a collective: that verdict, if any, names it
        looping = [r for r in range(self.comm.size) if state[r] == _ARMED]
        if looping and all(now - beat_at[r] > t for r in looping):
            age = min(now - beat_at[r] for r in looping)
            done = [r for r in range(self.comm.size) if state[r] == _FINISHED]
            return ([], looping), (
                f"pardem: error: watchdog: no progress on {_ranks(looping)} for {age:.0f} s although every rank "
                f"is alive (ranks waiting on each other, or one operation longer than {self._limit_name} "
                f"= {t:g})" + (f"; finished: {_ranks(done)}" if done else "") + "; aborting all ranks")
        return None

    @property
    def _limit_name(self):
        return ENV if self.script else "run.watchdog_seconds"

    def _stuck_message(self, now, state, calls, calls_at):
        """The line of a script whose ranks stay in a collective: every rank's whereabouts,
        ranks of the same description grouped."""
        groups = {}
        for r in range(self.comm.size):
            if state[r] == _FINISHED:
                key = ("finished", "has left the script and waits at its exit for the others")
            elif calls[r] % 2 == 1:
                key = ("inside", self._where[r] or "a collective")
            else:
                key = ("outside", self._where[r])
            groups.setdefault(key, []).append(r)
        parts = []
        for (kind, text), ranks in groups.items():
            if kind == "inside":
                age = min(now - calls_at[r] for r in ranks)
                parts.append(f"{_ranks(ranks)} {'has' if len(ranks) == 1 else 'have'} waited {age:.0f} s in {text}")
            elif kind == "outside":
                at = f", at {text}" if text else ""
                parts.append(f"{_ranks(ranks)} {'is' if len(ranks) == 1 else 'are'} outside any collective{at}")
            else:
                parts.append(f"{_ranks(ranks)} {text}")
        kinds = {kind for kind, _ in groups}
        why = "a collective called on some ranks only" if kinds != {"inside"} else "the ranks are in different collectives"
        return (f"pardem: error: watchdog: {'; '.join(parts)} ({why}? limit {self.timeout:g} s, "
                f"set by {ENV} or pardem.parallel.watchdog.configure, 0 = off); aborting all ranks")

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


def _text(slot):
    return slot[_HEAD:].tobytes().rstrip(b"\0").decode(errors="ignore")


_PARDEM = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))     # the pardem package
_THIS_LAYER = (os.path.join(_PARDEM, "parallel", "communicator.py"), os.path.abspath(__file__))
_LIBRARIES = tuple({os.path.abspath(sysconfig.get_paths()[k]) + os.sep for k in ("stdlib", "purelib", "platlib")})


def _place(frame, qualified):
    path = os.path.abspath(frame.f_code.co_filename)
    if path.startswith(_PARDEM + os.sep):
        path = os.path.relpath(path, os.path.dirname(_PARDEM))
    else:
        rel = os.path.relpath(path)
        path = path if rel.startswith("..") else rel
    name = f" ({frame.f_code.co_qualname})" if qualified and frame.f_code.co_qualname != "<module>" else ""
    return f"{path}:{frame.f_lineno}{name}"


def where(frame, calls):
    """Where a thread whose innermost frame is ``frame`` is: ``<collective> called from <pardem
    caller> <- <pardem entry> <- <script line>`` while ``calls`` (``COLLECTIVE.calls``) is odd,
    else ``<pardem function> <- <pardem entry> <- <script line>``: the innermost and the outermost
    pardem frame below the innermost frame of the user's code, each part absent if there is no
    such frame ("" without a frame)."""
    inner = outer = user = None
    while frame is not None and user is None:
        path = os.path.abspath(frame.f_code.co_filename)
        if path.startswith(_PARDEM + os.sep):
            if path not in _THIS_LAYER:
                inner, outer = inner or frame, frame
        elif not path.startswith(_LIBRARIES) and not path.startswith("<"):
            user = frame
        frame = frame.f_back
    if outer is inner:
        outer = None
    chain = " <- ".join(_place(f, f is not user) for f in (inner, outer, user) if f is not None)
    if calls % 2 == 1:
        return f"{COLLECTIVE.name} called from {chain}" if chain else COLLECTIVE.name
    return chain


def start(comm, timeout=DEFAULT_SECONDS):
    """Collective: start this process's watchdog (None on one rank: nobody can wait on another).
    ``timeout`` [s] without progress; 0 watches nothing until ``configure`` sets a limit. A script
    watchdog already running (``protect_script``) is taken over: the driver's limit, no watch of
    the collectives (a task farm's ranks wait for minutes in ``wait_for_all``)."""
    global _current
    if comm.size == 1:
        return _current
    if _current is None:
        _current = Watchdog(comm, timeout)
    elif _current.script:
        _current.timeout, _current.script = float(timeout), False
    return _current


def script_seconds():
    """The script watchdog's limit [s]: ``configure``'s, else ``$PARDEM_WATCHDOG_SECONDS``, else
    ``DEFAULT_SECONDS``."""
    if _script_seconds is not None:
        return _script_seconds
    text = os.environ.get(ENV, "").strip()
    if not text:
        return DEFAULT_SECONDS
    try:
        seconds = float(text)
    except ValueError:
        seconds = -1.0
    if not seconds >= 0 or seconds == float("inf"):
        raise ValueError(f"{ENV}={text!r}: expected a number of seconds >= 0 (0 = no script watchdog)")
    return seconds


def protect_script(comm):
    """Start the script watchdog on ``comm`` (``COMM_WORLD``, more than one rank) unless one ran
    already in this process or the limit is 0 (``Communicator`` calls it; not blocking). It also
    watches the collectives and stops at interpreter exit."""
    global _current, _protected
    if _protected or _current is not None or comm.size == 1:
        return
    _protected = True
    seconds = script_seconds()
    if seconds == 0:
        return
    _current = Watchdog(comm, seconds, script=True)
    atexit.register(_at_exit)


def _at_exit():
    """The script ended on this rank (or raised): wait, still watching, until every rank has,
    then end the watchdog's messages before ``MPI_Finalize``."""
    if _current is not None and _current.script:
        stop()


def configure(timeout):
    """Set the limit [s] of the running watchdog (the deck's ``run.watchdog_seconds``; 0 = off),
    and of a script watchdog started later. Local: every rank reads the same deck."""
    global _script_seconds
    if not timeout >= 0:
        raise ValueError(f"watchdog timeout {timeout}: expected >= 0")
    _script_seconds = float(timeout)
    if _current is not None:
        _current.timeout = float(timeout)


def stop():
    """This rank is finished: its slot says so; returns when every rank is (then the watchdog's
    messages end). Called by every rank at the end of ``cli.run_driver``."""
    global _current
    if _current is not None:
        _current.stop()
        _current = None
