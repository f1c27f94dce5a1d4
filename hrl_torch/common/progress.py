"""Progress bars drawn only on a terminal.

A tqdm bar redraws itself with carriage returns; in a log file (CI, ``nohup``, a pipe) each
redraw is debris. ``progress_bar`` draws only when asked and stderr (where tqdm writes) is a
terminal; otherwise it is disabled and the trainer's one line per evaluation
(``tqdm.write``) is all a log gets.
"""

from __future__ import annotations

import sys

from tqdm import tqdm


def on_terminal(stream=None) -> bool:
    """Whether ``stream`` (default ``sys.stderr``) is a terminal."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


def progress_bar(show: bool = True, **kwargs) -> tqdm:
    """``tqdm(**kwargs)``, disabled unless ``show`` and stderr is a terminal."""
    return tqdm(disable=not (show and on_terminal()), **kwargs)
