"""One writer per run folder: an exclusive lock held for the run's life.

Two ``--resume`` of one checkpoint at once would both append to ``progress.csv`` and both record
a resume in ``hparams.json``. The run takes ``flock(LOCK_EX | LOCK_NB)`` on ``RUN_DIR/.lock``
before it changes anything in the folder; a second writer is refused with the holder's pid and
changes nothing. The operating system drops the lock when the holder exits, however it exits
(``kill -9`` included), so no stale lock outlives a crash. Where ``fcntl`` does not exist
(Windows) runs are not locked. A link at ``.lock`` is refused, not written through
(``hrl_torch.common.safe_files``).
"""

from __future__ import annotations

import os
from pathlib import Path

from hrl_torch.common.safe_files import open_own

LOCK_NAME = ".lock"


class RunLockedError(RuntimeError):
    """Another process is writing the run folder."""


class RunLock:
    """``with RunLock(run_dir):`` holds the folder's lock (``RunLockedError`` if taken)."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir) / LOCK_NAME
        self._file = None

    def __enter__(self) -> RunLock:
        try:
            import fcntl
        except ImportError:  # no flock on this platform
            return self
        handle = open_own(self.path, "a+")  # held open while the run lives; no link followed
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            handle.close()
            raise RunLockedError(
                f"{self.path.parent} is in use by process {holder} (another run or resume "
                "writes it); wait for it to end"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        self._file = handle
        return self

    def __exit__(self, *exc) -> None:
        if self._file is not None:
            self._file.close()  # closing releases the lock
            self._file = None
