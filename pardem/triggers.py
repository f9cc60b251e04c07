"""Triggers: when an operation runs (HOOMD-blue's ``hoomd.trigger``).

A trigger is a boolean function of the step count: ``trigger(step)`` is true on the steps after
which its operation runs. ``Simulation.run`` asks it only about the steps it completes (never
about the step a run starts from) and calls an operation on no other step, except once at the end
of a run when the operation's ``at_end`` is true.

* ``Periodic(period, phase=0)``: the steps ``phase + k period``, k >= 0;
* ``At(steps)``: the given steps;
* ``Never()``: no step;
* ``After(step)``: the steps > ``step``; ``Before(step)``: the steps < ``step``;
* ``Or(triggers)``, ``And(triggers)``, ``Not(trigger)``; also ``a | b``, ``a & b``, ``~a``.

An int ``n`` stands for ``Periodic(n)`` (``as_trigger``). One trigger object may serve several
operations: triggers hold no state.

For speed, ``next_after(step)`` says which step to look at next: a step t > ``step`` such that the
trigger is false on every step strictly between them (None: false on every later step). It is the
next true step itself for ``Periodic``, ``At``, ``After``, ``Before``, ``Never`` and their ``Or``;
``And`` and ``Not`` may return an earlier step, on which ``run`` evaluates the trigger and asks
again. ``run`` thus runs no Python per operation on the steps between. A trigger written by the
user needs only ``__call__``: the default ``next_after`` is the next step (looked at every step).
"""
import bisect

import numpy as np

_AND_ROUNDS = 64   # And.next_after's look-ahead rounds before it settles for a lower bound


def _step(value, name, lo=0):
    """``value`` as an int >= ``lo`` (numpy integers too; bool, floats and others: ValueError)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < lo:
        raise ValueError(f"{name} = {value!r}: expected an integer >= {lo} (steps)")
    return int(value)


class Trigger:
    """Base class: a boolean function of the step count ``__call__(step) -> bool``."""

    def __call__(self, step):
        raise NotImplementedError

    def next_after(self, step):
        """A step t > ``step`` with the trigger false on ``(step, t)``, or None if it never fires
        after ``step``. Default: ``step + 1`` (valid for any trigger)."""
        return step + 1

    def __or__(self, other):
        return Or([self, as_trigger(other, "trigger")])

    def __ror__(self, other):
        return Or([as_trigger(other, "trigger"), self])

    def __and__(self, other):
        return And([self, as_trigger(other, "trigger")])

    def __rand__(self, other):
        return And([as_trigger(other, "trigger"), self])

    def __invert__(self):
        return Not(self)

    def _key(self):
        return None

    def __eq__(self, other):
        key = self._key()
        if key is None:
            return self is other
        return type(other) is type(self) and other._key() == key

    def __hash__(self):
        key = self._key()
        return id(self) if key is None else hash((type(self).__name__, key))


class Periodic(Trigger):
    """True on the steps ``phase + k period`` (k >= 0): every ``period`` steps from ``phase`` on."""

    def __init__(self, period, phase=0):
        self.period = _step(period, "period", lo=1)
        self.phase = _step(phase, "phase")

    def __call__(self, step):
        return step >= self.phase and (step - self.phase) % self.period == 0

    def next_after(self, step):
        if step < self.phase:
            return self.phase
        return step + self.period - (step - self.phase) % self.period

    def _key(self):
        return (self.period, self.phase)

    def __repr__(self):
        return f"Periodic({self.period}" + (f", phase={self.phase})" if self.phase else ")")


class At(Trigger):
    """True on the given steps only (an int or an iterable of ints >= 0)."""

    def __init__(self, steps):
        if isinstance(steps, (int, np.integer)) and not isinstance(steps, (bool, np.bool_)):
            steps = [steps]
        try:
            steps = list(steps)
        except TypeError:
            raise ValueError(f"steps = {steps!r}: expected an integer >= 0 or a list of them") from None
        self.steps = tuple(sorted({_step(s, "steps") for s in steps}))
        self._set = frozenset(self.steps)

    def __call__(self, step):
        return step in self._set

    def next_after(self, step):
        i = bisect.bisect_right(self.steps, step)
        return self.steps[i] if i < len(self.steps) else None

    def _key(self):
        return self.steps

    def __repr__(self):
        return f"At({list(self.steps)})"


class Never(Trigger):
    """False on every step (an operation called only at the end of runs, or by hand)."""

    def __call__(self, step):
        return False

    def next_after(self, step):
        return None

    def _key(self):
        return ()

    def __repr__(self):
        return "Never()"


class After(Trigger):
    """True on the steps strictly after ``step``."""

    def __init__(self, step):
        self.step = _step(step, "step")

    def __call__(self, step):
        return step > self.step

    def next_after(self, step):
        return max(step + 1, self.step + 1)

    def _key(self):
        return (self.step,)

    def __repr__(self):
        return f"After({self.step})"


class Before(Trigger):
    """True on the steps strictly before ``step``."""

    def __init__(self, step):
        self.step = _step(step, "step")

    def __call__(self, step):
        return step < self.step

    def next_after(self, step):
        return step + 1 if step + 1 < self.step else None

    def _key(self):
        return (self.step,)

    def __repr__(self):
        return f"Before({self.step})"


def _children(triggers, name):
    if isinstance(triggers, (Trigger, int, np.integer)):
        triggers = [triggers]
    out = tuple(as_trigger(t, f"{name} operand") for t in triggers)
    if not out:
        raise ValueError(f"{name}: expected at least one trigger")
    return out


class Or(Trigger):
    """True when any of ``triggers`` is."""

    def __init__(self, triggers):
        self.triggers = _children(triggers, "Or")

    def __call__(self, step):
        return any(t(step) for t in self.triggers)

    def next_after(self, step):
        # the earliest look of any operand: no operand fires before it, so neither does the Or
        nxt = [n for n in (t.next_after(step) for t in self.triggers) if n is not None]
        return min(nxt) if nxt else None

    def _key(self):
        return self.triggers

    def __repr__(self):
        return f"Or({list(self.triggers)})"


class And(Trigger):
    """True when all of ``triggers`` are."""

    def __init__(self, triggers):
        self.triggers = _children(triggers, "And")

    def __call__(self, step):
        return all(t(step) for t in self.triggers)

    def next_after(self, step):
        # the latest look of the operands is a lower bound (that operand is false before it);
        # moving on from there while it is not a common true step finds the next one, but some
        # combinations never fire (Periodic(2) and Periodic(2, phase=1)): after a few rounds
        # the lower bound is returned and run() asks again from there
        t = step
        for _ in range(_AND_ROUNDS):
            nxt = [c.next_after(t) for c in self.triggers]
            if any(n is None for n in nxt):
                return None
            m = max(nxt)
            if all(c(m) for c in self.triggers):
                return m
            t = m
        return t + 1

    def _key(self):
        return self.triggers

    def __repr__(self):
        return f"And({list(self.triggers)})"


class Not(Trigger):
    """True when ``trigger`` is false (looked at every step: ``next_after`` is the next step,
    unless the operand is an ``After``, whose negation ends)."""

    def __init__(self, trigger):
        self.trigger = as_trigger(trigger, "Not operand")

    def __call__(self, step):
        return not self.trigger(step)

    def next_after(self, step):
        if isinstance(self.trigger, After):
            return step + 1 if step + 1 <= self.trigger.step else None
        return step + 1

    def _key(self):
        return (self.trigger,)

    def __repr__(self):
        return f"Not({self.trigger!r})"


def as_trigger(value, name="trigger"):
    """``value`` as a ``Trigger``: a Trigger as it is, an int n >= 1 as ``Periodic(n)`` (numpy
    integers too); anything else (bool, float, None, 0): ValueError naming ``name``."""
    if isinstance(value, Trigger):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        if value < 1:
            raise ValueError(f"{name} = {value!r}: expected a period, an integer >= 1 (steps), "
                             f"or a Trigger (pardem.triggers)")
        return Periodic(int(value))
    raise ValueError(f"{name} = {value!r}: expected a period, an integer >= 1 (steps), or a Trigger "
                     f"(Periodic, At, Never, Or, ...: pardem.triggers)")


__all__ = ["Trigger", "Periodic", "At", "Never", "After", "Before", "Or", "And", "Not", "as_trigger"]
