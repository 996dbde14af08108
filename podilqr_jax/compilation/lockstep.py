"""Several solves in lockstep: their stage calls met and run as one batched call.

``restarts = k`` (``ilqr.restarts``) runs k solves of one task from different
first guesses. Each keeps its own driver (its own host logic: accepted and
rejected steps, mu, the recoveries, the stopping rules), in a thread of its
own; what they share is every call of a jitted stage (``stages.stage``). Inside
a :class:`Group` a stage call is *submitted* and the thread waits. When every
solve still running is waiting, the calls are grouped by stage and signature
(static arguments, pytree structure, shapes), and the largest group runs as
one call of the stage under ``jax.vmap``: a leading problem axis through the
rollouts, the fit, the backward pass and the line search, so on an
accelerator k starts should cost about one batch. Each solve then gets its own slice
and runs on to its next stage call. Arguments that every solve passes as the
same object (the task's arrays, the step sizes) are passed once, unbatched.

The schedule depends only on what the solves submit, never on thread timing:
a batch runs only when every live solve is waiting, the group is the largest
(then the one whose oldest call waited longest, then the lowest solve), so a
solve's numbers are the same from run to run. Solves that drift apart (one
rejects a step and redoes its backward pass while another identifies) meet
again at the next stage they share; a call left waiting for
``MAX_WAIT_ROUNDS`` batches runs next whatever its group's size.

Batch widths: on an accelerator every batch is k wide (the calls of fewer
solves padded with copies of the first; one program per stage); on a CPU,
where a padded rollout costs as much as a real one, the next power of two
(at most k; one program per stage and width, compiled when a width is first
met). A group of one runs as the plain stage call. A solve whose stage call
raises gets the exception in its own thread; so does every solve in a batch
that raised.

:meth:`Group.abort` (a second Ctrl-C) makes every waiting and later
submission raise ``KeyboardInterrupt`` in its solve's thread.
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import Any, Callable, Iterator, Optional

import jax
import jax.numpy as jnp

from . import xla_options

MAX_WAIT_ROUNDS = 8
"""Batches a submitted call may wait behind larger groups before it runs next."""

_local = threading.local()
_programs: dict[Any, Callable] = {}  # (signature, shared leaves, width) -> the batched program, for the process
_programs_lock = threading.Lock()


def current() -> Optional["Member"]:
    """The lockstep membership of this thread, or None outside a group."""
    return getattr(_local, "member", None)


def waited() -> float:
    """The seconds this thread's stage calls have waited in its group so far for
    the other solves to reach theirs (0 outside a group): a stage call's time
    is this wait and then its batch's run."""
    m = current()
    return m.waited if m is not None else 0.0


class _Call:
    """One solve's submitted stage call, and then its outcome."""

    def __init__(self, member: int, signature, fun: Callable, static: dict, leaves: list, treedef, solo: Callable):
        self.member, self.signature, self.fun, self.static = member, signature, fun, static
        self.leaves, self.treedef, self.solo = leaves, treedef, solo
        self.round = 0
        self.ran = 0.0  # seconds its batch ran
        self.done = False
        self.value: Any = None
        self.error: Optional[BaseException] = None


class Group:
    """k solves in lockstep (module docstring). ``size`` solves, each entering
    with :meth:`member` in its own thread; ``padded``: every batch ``size``
    wide (an accelerator) rather than the next power of two."""

    def __init__(self, size: int, padded: Optional[bool] = None):
        self.size = int(size)
        self.padded = jax.default_backend() != "cpu" if padded is None else bool(padded)
        self.live = self.size
        self.pending: dict[int, _Call] = {}
        self.rounds = 0
        self.aborted = False
        self.batches: dict[int, int] = {}  # width -> batched calls run (a group of one: width 1)
        self._cond = threading.Condition()

    @contextlib.contextmanager
    def member(self, index: int) -> Iterator["Member"]:
        """This thread as solve ``index`` of the group until the block ends (then it leaves)."""
        m = Member(self, index)
        _local.member = m
        try:
            yield m
        finally:
            _local.member = None
            with self._cond:
                self.live -= 1
                self._run_ready()

    def step_out(self) -> None:
        """A solve of the group stops submitting for a while (it waits at a race's
        rung, ``ilqr.race``): the others' calls no longer wait for it."""
        with self._cond:
            self.live -= 1
            self._run_ready()

    def step_in(self, n: int) -> None:
        """``n`` solves that stepped out submit again: every batch waits for them."""
        with self._cond:
            self.live += n

    def abort(self) -> None:
        """Every waiting and later submission raises ``KeyboardInterrupt``."""
        with self._cond:
            self.aborted = True
            self._cond.notify_all()

    def width(self, n: int) -> int:
        """The batch width of a group of ``n`` calls (module docstring)."""
        if self.padded:
            return self.size
        w = 1
        while w < n:
            w *= 2
        return min(w, self.size)

    # ---------------------------------------------------------------- rendezvous
    def submit(self, call: _Call) -> Any:
        with self._cond:
            if self.aborted:
                raise KeyboardInterrupt
            call.round = self.rounds
            self.pending[call.member] = call
            self._run_ready()
            while not call.done and not self.aborted:
                self._cond.wait()
            if not call.done:
                self.pending.pop(call.member, None)
                raise KeyboardInterrupt
        if call.error is not None:
            raise call.error
        return call.value

    def _run_ready(self) -> None:
        """With the lock held: while every live solve waits, run one group."""
        while self.pending and len(self.pending) >= self.live and not self.aborted:
            chosen = self._choose()
            for c in chosen:
                del self.pending[c.member]
            self.rounds += 1
            t0 = time.perf_counter()
            try:
                values = self._execute(chosen)
                for c, v in zip(chosen, values, strict=True):
                    c.value = v
            except BaseException as exc:  # noqa: BLE001 - handed to each solve of the batch, in its own thread
                for c in chosen:
                    c.error = exc
            ran = time.perf_counter() - t0
            for c in chosen:
                c.ran = ran
                c.done = True
            self._cond.notify_all()

    def _choose(self) -> list[_Call]:
        groups: dict[Any, list[_Call]] = {}
        for m in sorted(self.pending):
            c = self.pending[m]
            groups.setdefault(c.signature, []).append(c)
        ranked = list(groups.values())
        starved = [g for g in ranked if self.rounds - min(c.round for c in g) >= MAX_WAIT_ROUNDS]
        if starved:
            ranked = starved
        return max(ranked, key=lambda g: (len(g), -min(c.round for c in g), -g[0].member))

    def _execute(self, calls: list[_Call]) -> list[Any]:
        """Run ``calls`` (one signature) as one batched call; their outputs in order."""
        n = len(calls)
        width = self.width(n)
        self.batches[width] = self.batches.get(width, 0) + 1
        if width == 1:
            return [calls[0].solo()]
        first = calls[0]
        # a leaf every solve passes as the same object goes in once, unbatched
        shared = tuple(all(c.leaves[j] is first.leaves[j] for c in calls) for j in range(len(first.leaves)))
        if all(shared):  # the same call n times: once
            return [first.solo()] * n
        key = (first.signature, shared, width)
        with _programs_lock:
            program = _programs.get(key)
            if program is None:
                program = _programs[key] = _batched(first.fun, first.static, first.treedef, shared, width)
        members = [c.leaves for c in calls] + [first.leaves] * (width - n)
        shared_leaves = [leaf if s else None for leaf, s in zip(first.leaves, shared, strict=True)]
        per_member = [[leaf for leaf, s in zip(leaves, shared, strict=True) if not s] for leaves in members]
        outputs = program(shared_leaves, per_member)
        return list(outputs[:n])


class Member:
    """A solve's place in a :class:`Group` (``current()`` in its thread)."""

    def __init__(self, group: Group, index: int):
        self.group, self.index = group, index
        self.waited = 0.0  # ``waited()``

    def submit(self, name: str, fun: Callable, static: dict, traced: dict, solo: Callable) -> Any:
        """Run stage ``name`` (``fun`` with the ``static`` keyword arguments and
        the ``traced`` ones) batched with the other solves' calls; ``solo`` runs
        this call alone, as outside the group."""
        leaves, treedef = jax.tree_util.tree_flatten(traced)
        avals = tuple(jax.typeof(leaf) for leaf in leaves)
        signature = (name, tuple(static.items()), treedef, avals)  # static: in the stage's own order
        call = _Call(self.index, signature, fun, static, leaves, treedef, solo)
        t0 = time.perf_counter()
        try:
            return self.group.submit(call)
        finally:
            self.waited += max(0.0, time.perf_counter() - t0 - call.ran)


def _batched(fun: Callable, static: dict, treedef, shared: tuple, width: int) -> Callable:
    """The jitted program of ``width`` calls of ``fun``: it takes the shared leaves
    once and the others per call, stacks those, runs ``vmap(fun)`` and returns
    each call's output."""

    def one(shared_leaves, batched_leaves):
        it = iter(batched_leaves)
        leaves = [s if is_shared else next(it) for s, is_shared in zip(shared_leaves, shared, strict=True)]
        return fun(**static, **jax.tree_util.tree_unflatten(treedef, leaves))

    def program(shared_leaves, per_member):
        stacked = [jnp.stack(column) for column in zip(*per_member, strict=True)]
        out = jax.vmap(one, in_axes=(None, 0))(shared_leaves, stacked)
        return tuple(jax.tree_util.tree_map(lambda a, i=i: a[i], out) for i in range(width))

    return xla_options.top_level(program)
