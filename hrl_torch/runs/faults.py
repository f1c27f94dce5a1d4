"""Any error reached through the CLI as one line, naming the user's file and line.

A domain module's own code (its env factory, its task graph, an abstraction) fails inside
hrl-torch's calls; the traceback's last frame outside hrl-torch, torch and the standard
library is the user's line the error comes from. ``one_line`` puts it in the message, so
``hrl-torch: error: ValueError: grid must be square (my_domain.py:12)`` says where to look
without ``--debug``.
"""

from __future__ import annotations

import os
import sys
import sysconfig
import traceback

_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep  # hrl_torch/
_LIBRARIES = tuple(
    {os.path.abspath(p) + os.sep for p in (sysconfig.get_paths()["stdlib"],
     sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]) if p}
)  # fmt: skip


def _is_library(filename: str) -> bool:
    path = os.path.abspath(filename)
    return (
        filename.startswith("<")
        or path.startswith(_PACKAGE)
        or path.startswith(_LIBRARIES)
        or "site-packages" in path.split(os.sep)
    )


def user_frame(err: BaseException) -> str | None:
    """``file:line`` of the last traceback frame in the user's code (``None``: none)."""
    seen, found = set(), None
    while err is not None and id(err) not in seen:  # the cause's frames are the deepest
        seen.add(id(err))
        for frame in traceback.extract_tb(err.__traceback__):
            if not _is_library(frame.filename):
                found = f"{os.path.relpath(frame.filename)}:{frame.lineno}"
        if found is not None:
            return found
        err = err.__cause__ or err.__context__
    return None


def one_line(err: BaseException, with_type: bool = True) -> str:
    """``err`` in one line: its type (unless ``with_type`` is off), message and user's line."""
    text = " ".join(str(err).split()) or type(err).__name__
    if with_type and not text.startswith(type(err).__name__):
        text = f"{type(err).__name__}: {text}"
    where = user_frame(err)
    if where is not None and where not in text:
        text += f" ({where})"
    return text


def report(err: BaseException) -> int:
    """Print an unexpected error in one line; exit status 1."""
    where = user_frame(err)
    hint = "" if where else "; rerun with --debug for the traceback"
    print(f"hrl-torch: error: {one_line(err)}{hint}", file=sys.stderr)
    return 1
