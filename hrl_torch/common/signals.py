"""Signals in a run's phases: SIGINT and SIGTERM are handled alike at every phase.

- ``raise_on_signals`` (the CLI, around everything): SIGTERM raises ``Interrupted`` as SIGINT
  raises ``KeyboardInterrupt``, so a start cut short cleans up the same way for both.
- ``StopOnSignal`` (training, its final evaluation and save; the summary after it): the first
  signal is recorded, not raised, and the phase finishes cleanly. Long loops inside it (a
  greedy evaluation) poll ``stop_requested()`` every step and stop within one step.
- ``signals_deferred`` (a checkpoint write): both signals wait until the write is done, so no
  second signal cuts it and leaves a stale temporary file.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

CAUGHT = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM raised outside a guarded phase; ``signal`` is its name."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.signal = name


@contextmanager
def raise_on_signals():
    """Within: SIGINT and SIGTERM raise ``Interrupted`` (outside the main thread: unchanged)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise Interrupted(signal.Signals(signum).name)

    previous = {s: signal.signal(s, interrupt) for s in CAUGHT}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextmanager
def signals_deferred():
    """Within: SIGINT and SIGTERM are recorded and raised again, each once, when it ends.

    (Blocking them with ``pthread_sigmask`` is not enough: another thread would take them and
    Python would still run the handler in the main thread.)
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {s: signal.signal(s, lambda signum, frame: caught.append(signum)) for s in CAUGHT}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for signum in dict.fromkeys(caught):  # several of one kind count once
            signal.raise_signal(signum)


class StopOnSignal:
    """Within ``with``: the first SIGINT or SIGTERM is recorded, not raised.

    ``signal`` holds its name; the previous handlers come back at once, so a second signal
    acts as usual. Outside the main thread (where handlers cannot be set) nothing changes.
    While one is entered, ``stop_requested()`` says whether it caught a signal.
    """

    SIGNALS = CAUGHT
    _active: list[StopOnSignal] = []  # entered and not yet left, innermost last

    def __init__(self) -> None:
        self.signal: str | None = None
        self._previous: dict = {}

    def __enter__(self) -> StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            self._previous = {s: signal.signal(s, self._record) for s in self.SIGNALS}
        StopOnSignal._active.append(self)
        return self

    def _record(self, signum, frame) -> None:
        self.signal = signal.Signals(signum).name
        self._restore()

    def _restore(self) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous = {}

    def __exit__(self, *exc) -> None:
        self._restore()
        if self in StopOnSignal._active:
            StopOnSignal._active.remove(self)


def stop_requested() -> str | None:
    """The signal an entered ``StopOnSignal`` caught (its name), else ``None``.

    A loop that may run long inside a guarded phase (a greedy evaluation of minutes) asks this
    every step and ends early when it is set; it costs a list lookup.
    """
    for stop in StopOnSignal._active:
        if stop.signal is not None:
            return stop.signal
    return None
