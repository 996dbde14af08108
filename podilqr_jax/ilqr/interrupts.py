"""Ctrl-C, and a scheduler's stop, that land at an iteration boundary, whenever they come.

A ``KeyboardInterrupt`` raised wherever the signal happens to land can leave
a solve half-updated, and when it lands in a finaliser or a weakref callback
(JAX runs many) Python prints "Exception ignored ..." with a traceback and
carries on, so the solve never stops. Inside :data:`deferred_interrupts`
(the solver's loop, the CLI's ``solve``) the first stop signal only
*requests* a stop: the driver reads ``requested`` after each completed
iteration (and before the first) and returns the result so far with status
``interrupted``, writing its final checkpoint. A second one raises
``KeyboardInterrupt`` at once, for a user who will not wait for the iteration
to end; the driver then falls back to the last completed iteration's snapshot.

The stop signals (``STOP_SIGNALS``) are SIGINT (Ctrl-C) and what schedulers
send before they kill a job: SIGTERM (``timeout``, SLURM, Kubernetes, systemd),
SIGHUP (a closed terminal or session) and SIGUSR1 (SLURM's ``--signal`` ahead
of the time limit). ``signal`` says which one came; the CLI exits with 128 +
its number (130 for Ctrl-C, 143 for SIGTERM).

A handler is installed only from the main thread and only over the signal's
default one, so a caller's own handling (a notebook kernel, a service) is left
as it is: ``active`` says whether any request is being deferred. Nested
``with`` blocks share one request.
"""

from __future__ import annotations

import os
import signal
import threading
from typing import Optional

STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGUSR1") if hasattr(signal, name)
)
"""The signals that stop a solve at the next iteration boundary (module docstring)."""


def _default(signum: int):
    """The handler Python starts with for ``signum``: its own for SIGINT, the system's otherwise."""
    return signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL


def signal_name(signum: int) -> str:
    return "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name


class DeferredInterrupts:
    """A re-entrant context in which the first stop signal sets ``requested``."""

    def __init__(self) -> None:
        self.requested = False
        self.signal: Optional[int] = None  # the signal that requested the stop
        self._depth = 0
        self._previous: dict[int, object] = {}

    @property
    def active(self) -> bool:
        return bool(self._previous)

    def __enter__(self) -> "DeferredInterrupts":
        if self._depth == 0:
            self.requested, self.signal = False, None
            if threading.current_thread() is threading.main_thread():
                for signum in STOP_SIGNALS:
                    if signal.getsignal(signum) is _default(signum):
                        self._previous[signum] = signal.signal(signum, self._handle)
        self._depth += 1
        return self

    def __exit__(self, *exc: object) -> bool:
        self._depth -= 1
        if self._depth == 0:
            for signum, previous in self._previous.items():
                signal.signal(signum, previous)
            self._previous = {}
        return False

    @property
    def exit_status(self) -> int:
        """The shell's status for a process ended by the requesting signal: 128 + its number."""
        return 128 + (self.signal if self.signal is not None else signal.SIGINT)

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested, self.signal = True, signum
        again = "press it again" if signum == signal.SIGINT else "send it again"
        notice = f"\n{signal_name(signum)}: stopping after the current iteration and writing the result so far"
        notice += f" ({again} to stop at once)\n"
        try:  # os.write is safe in a signal handler; print is not (re-entrant buffers)
            os.write(2, notice.encode())
        except OSError:
            pass


deferred_interrupts = DeferredInterrupts()
