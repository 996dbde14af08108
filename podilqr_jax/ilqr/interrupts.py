"""Ctrl-C that lands at an iteration boundary, whenever it is pressed.

A ``KeyboardInterrupt`` raised wherever the signal happens to land can leave
a solve half-updated, and when it lands in a finaliser or a weakref callback
(JAX runs many) Python prints "Exception ignored ..." with a traceback and
carries on, so the solve never stops. Inside :data:`deferred_interrupts`
(the solver's loop, the CLI's ``solve``) the first SIGINT only *requests* a
stop: the driver reads ``requested`` after each completed iteration (and
before the first) and returns the result so far with status
``interrupted``. A second SIGINT raises ``KeyboardInterrupt`` at once, for a
user who will not wait for the iteration to end; the driver then falls back
to the last completed iteration's snapshot.

The handler is installed only from the main thread and only over Python's
default one, so a caller's own SIGINT handling (a notebook kernel, a
service) is left as it is: ``active`` says whether requests are being
deferred. Nested ``with`` blocks share one request.
"""

from __future__ import annotations

import os
import signal
import threading
from typing import Optional

_NOTICE = b"\nCtrl-C: stopping after the current iteration (press it again to stop at once)\n"


class DeferredInterrupts:
    """A re-entrant context in which the first SIGINT sets ``requested``."""

    def __init__(self) -> None:
        self.requested = False
        self._depth = 0
        self._previous: Optional[object] = None

    @property
    def active(self) -> bool:
        return self._previous is not None

    def __enter__(self) -> "DeferredInterrupts":
        if self._depth == 0:
            self.requested = False
            main = threading.current_thread() is threading.main_thread()
            if main and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
                self._previous = signal.signal(signal.SIGINT, self._handle)
        self._depth += 1
        return self

    def __exit__(self, *exc: object) -> bool:
        self._depth -= 1
        if self._depth == 0 and self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None
        return False

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        try:  # os.write is safe in a signal handler; print is not (re-entrant buffers)
            os.write(2, _NOTICE)
        except OSError:
            pass


deferred_interrupts = DeferredInterrupts()
