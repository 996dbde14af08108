"""Starts raced against each other: successive halving over iterations, with a margin.

With ``restarts = k`` every start is a solve of its own (``restarts``), and
on a robot most of the physics goes to starts that lose: each runs until it
converges or reaches ``max_iterations``, however far above the best it is.
The race stops them early. Its rungs are iterations ``b, 2b, 4b, ...``
(``b = race_rung``). At a rung the *field*, the starts no rung has cut, is
ranked by the score each had after that iteration (the noiseless cost, or
under noise the true, noiseless closed-loop cost of the policy; a start that
stopped before the rung is ranked by its last score). Every start still
running in the worse half (the better half rounded up stays) whose score is
above ``race_margin`` times the best one's stops there with the status
``outraced``: successive halving (Jamieson and Talwalkar, 2016) with the
iterations as the budget, where a start close behind the best is kept. A
field of one ends the race, and the solve ends when that start does.

The ranking at a rung is a function of the starts' score histories alone, not
of which thread arrives first: a start that reaches a rung waits there, out of
the lockstep group (``lockstep.Group.step_out``), until every start of the field
has reached it or stopped; the last one to arrive ranks them and puts every
waiting start back in the group at once, so the batches that follow are the
same from run to run. A resumed solve ranks its rungs again from the histories
in its checkpoints and cuts the same starts.

A start is cut for being far behind at a rung, not for being unable to catch
up: one whose cost falls late (a walker that lands in a better stance) can
lose the race and the lower minimum with it; the margin and a first rung well
into the solve are the guard (``benchmarks/race.py`` replays other rules on
solves without the race). ``race_rung = 0`` runs every start to its own end.
"""

from __future__ import annotations

import math
import threading
from typing import Callable, Optional, Sequence

from .result import Status
from .stopping import Stop


def rungs(first: int, max_iterations: int) -> list[int]:
    """The rung iterations b, 2b, 4b, ... below ``max_iterations`` (none for b = 0)."""
    out, r = [], first
    while 0 < r < max_iterations:
        out.append(r)
        r *= 2
    return out


def score_at(scores: Sequence[float], rung: int) -> float:
    """A start's score after iteration ``rung``, or its last one where it stopped before."""
    return scores[rung] if len(scores) > rung else (scores[-1] if len(scores) else math.inf)


def rank(field: Sequence[int], scores: Sequence[Sequence[float]], ended: Sequence[bool], rung: int, margin: float):
    """The starts of ``field`` best first by their score after iteration
    ``rung`` (``scores[j][rung]``; the last one of a start that ended before
    it), ties to the lower start, and those of the worse half whose score
    there is above ``margin`` times the best's (the ones the rung takes out);
    None where a start still running has not reached the rung."""
    if any(len(scores[j]) <= rung and not ended[j] for j in field):
        return None
    at = {j: score_at(scores[j], rung) for j in field}
    ranked = sorted(field, key=lambda j: (at[j], j))
    best = at[ranked[0]]
    return ranked, [j for j in ranked[(len(field) + 1) // 2 :] if at[j] > margin * best]


def replay(
    histories: Sequence[Sequence[float]], first: int, max_iterations: int, margin: float
) -> tuple[dict[int, int], list[float]]:
    """The race over starts that all ran to their own end with these score
    histories (a solve with ``race_rung = 0``): which rung would have cut
    which start, and each start's score where it would have stopped. What
    the starts kept would have run is what they ran, so this answers, from
    one solve, what a race with its first rung at ``first`` and ``margin``
    keeps and spends."""
    scores = [[_finite(s) for s in h] for h in histories]
    ended = [True] * len(scores)
    cut: dict[int, int] = {}
    for rung in rungs(first, max_iterations):
        field = [j for j in range(len(scores)) if j not in cut]
        if len(field) <= 1:
            break
        _, out = rank(field, scores, ended, rung, margin)
        for j in out:
            cut[j] = rung
    cut = {j: r for j, r in cut.items() if len(scores[j]) - 1 > r}  # a start that had ended is not cut
    final = [score_at(s, cut.get(j, len(s))) for j, s in enumerate(scores)]
    return cut, final


class Race:
    """The race of ``size`` starts (module docstring) with its first rung at
    iteration ``first``; ``step_out()`` and ``step_in(n)`` take a waiting start
    out of the lockstep group and put n back (``lockstep.Group``)."""

    def __init__(
        self, size: int, first: int, margin: float, max_iterations: int, step_out: Callable, step_in: Callable
    ):
        self.size, self.margin = size, margin
        self.rungs = rungs(first, max_iterations)
        self._step_out, self._step_in = step_out, step_in
        self._scores: list[list[float]] = [[] for _ in range(size)]  # the score after iteration i at [i]
        self._ended = [False] * size  # stopped for good: its last score is final
        self._gone = False  # a start left without a final score (Ctrl-C, an error)
        self.cut: dict[int, int] = {}  # a start still running -> the rung that cut it
        self._dropped: set[int] = set()  # ... and the starts that had ended, out of the field too
        self.ranked: dict[int, list[int]] = {}  # rung -> the field there, best first
        self._waiting: set[int] = set()  # out of the group at a rung
        self._put_back: set[int] = set()  # ... put back in by the start that ranked the rung
        self._cond = threading.Condition()

    # ---------------------------------------------------------------- reports
    def ended(self, start: int, scores: Sequence[float]) -> None:
        """Start ``start`` stopped for good (converged, failed, outraced, at max_iterations) with these scores."""
        with self._cond:
            self._scores[start] = [_finite(s) for s in scores]
            self._ended[start] = True
            self._rank_ready()

    def gone(self) -> None:
        """A start left without a final score: the rungs it had not reached cannot be ranked."""
        with self._cond:
            self._gone = True
            self._cond.notify_all()

    def after_iteration(self, start: int, scores: Sequence[float], interrupted: Callable[[], bool]) -> Optional[Stop]:
        """Start ``start`` completed iteration ``len(scores) - 1`` with these
        scores; at a rung it waits for the ranking (module docstring). Returns
        the ``outraced`` stop where a rung cuts it, else None (also where the
        rung cannot be ranked: a Ctrl-C, a start that failed)."""
        rung = len(scores) - 1
        with self._cond:
            self._scores[start] = [_finite(s) for s in scores]
            self._rank_ready()
            if start in self.cut or rung not in self.rungs or self._settled(rung):
                return self._stop_of(start)
            self._waiting.add(start)
            self._step_out()
            try:
                while not self._settled(rung) and not (interrupted() or self._gone):
                    self._cond.wait(0.2)
            finally:
                self._waiting.discard(start)
                if start in self._put_back:
                    self._put_back.discard(start)
                else:  # no ranking put it back (a Ctrl-C, a failed start): on its own
                    self._step_in(1)
            return self._stop_of(start)

    # ---------------------------------------------------------------- ranking
    def _field(self) -> list[int]:
        return [j for j in range(self.size) if j not in self.cut and j not in self._dropped]

    def _settled(self, rung: int) -> bool:
        return rung in self.ranked or len(self._field()) <= 1

    def _rank_ready(self) -> None:
        """Rank every rung that can be ranked now, in order; the starts waiting
        there go back into the lockstep group together, before any of them runs on."""
        for rung in self.rungs:
            if rung in self.ranked:
                continue
            if not self._rank(rung):
                break
        back = {j for j in self._waiting - self._put_back if self._settled(len(self._scores[j]) - 1)}
        if back:
            self._put_back |= back
            self._step_in(len(back))
            self._cond.notify_all()

    def _rank(self, rung: int) -> bool:
        """Rank the field at ``rung`` (``rank``); False where a member has not reached it yet."""
        field = self._field()
        if len(field) <= 1:
            return False
        ranking = rank(field, self._scores, self._ended, rung, self.margin)
        if ranking is None:
            return False
        self.ranked[rung] = ranking[0]
        for j in ranking[1]:
            if self._ended[j]:
                self._dropped.add(j)
            else:
                self.cut[j] = rung
        return True

    def _stop_of(self, start: int) -> Optional[Stop]:
        rung = self.cut.get(start)
        if rung is None:
            return None
        ranked = self.ranked[rung]
        best = ranked[0]
        mine, lowest = score_at(self._scores[start], rung), score_at(self._scores[best], rung)
        return Stop(
            Status.OUTRACED,
            f"outraced at iteration {rung}: its cost {mine:.6g} was in the worse half of "
            f"the {len(ranked)} starts racing there and above {self.margin:g} x the lowest "
            f"({lowest:.6g}, start {best}); race_rung = 0 runs every start to its end",
        )


def _finite(x: float) -> float:
    x = float(x)
    return x if math.isfinite(x) else math.inf
