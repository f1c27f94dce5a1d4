"""A signal guard for training loops: the first SIGINT or SIGTERM ends the run cleanly."""

from __future__ import annotations

import signal
import threading


class StopOnSignal:
    """Within ``with``: the first SIGINT or SIGTERM is recorded, not raised.

    ``signal`` holds its name; the previous handlers come back at once, so a second signal
    acts as usual. Outside the main thread (where handlers cannot be set) nothing changes.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signal: str | None = None
        self._previous: dict = {}

    def __enter__(self) -> StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            self._previous = {s: signal.signal(s, self._record) for s in self.SIGNALS}
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
