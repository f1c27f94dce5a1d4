"""A run folder checked before a resume (or an evaluation) reads or writes it.

What ``RunLogger`` and the checkpoint write, by kind: ``.lock``, ``hparams.json``,
``summary.json``, ``progress.csv``, ``eval_episodes.csv``, ``checkpoint.pt`` and the ``*.png``
curves are plain files; ``tb/`` and ``tb/seed_<s>/`` are folders (of TensorBoard event files).
``check_run_folder`` refuses a folder that holds a link anywhere, one of these of the wrong
kind, a CSV log whose first line is not hrl-torch's header (rows would be appended under
someone else's columns) or an ``hparams.json`` that is not a JSON object, each in one line
naming the entry and what to do.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from hrl_torch.common.safe_files import RunFolderError, check_tree
from hrl_torch.training.runlog import EPISODE_COLUMNS, PROGRESS_HEADER

FILES = frozenset(
    {".lock", "hparams.json", "summary.json", "progress.csv", "eval_episodes.csv", "checkpoint.pt"}
)
#: the headers each CSV may start with (eval_episodes.csv: begun before its ``loop`` and
#: ``partial`` columns too)
HEADERS = {
    "progress.csv": (PROGRESS_HEADER,),
    "eval_episodes.csv": tuple(",".join(EPISODE_COLUMNS[:n]) + "\n" for n in (11, 10, 9)),
}
_SEED_FOLDER = re.compile(r"tb/seed_-?\d+")


def entry_kind(relative: str) -> str | None:
    """``'file'``, ``'folder'`` or ``None`` (not one of the run's own) for a run-folder entry."""
    if relative in FILES or ("/" not in relative and relative.endswith(".png")):
        return "file"
    if relative == "tb" or _SEED_FOLDER.fullmatch(relative):
        return "folder"
    if _SEED_FOLDER.fullmatch(relative.rsplit("/", 1)[0]):
        return "file"  # an event file
    return None


def check_run_folder(run_dir: str | Path) -> dict | None:
    """Refuse a damaged or planted run folder; return its ``hparams.json`` (``None``: none).

    Raises:
        RunFolderError: naming the entry that is wrong and what to do.
    """
    run_dir = Path(run_dir)
    if not run_dir.exists():
        return None  # (no folder: the checkpoint's load says so)
    if not run_dir.is_dir():
        raise RunFolderError(f"{run_dir} is not a folder")
    check_tree(run_dir, entry_kind)
    for name, headers in HEADERS.items():
        path = run_dir / name
        if not path.exists():
            continue
        header = headers[0]
        with open(path, "rb") as f:
            first = f.readline(max(map(len, headers)) + 1)
        if first and first.decode("utf-8", "replace") not in headers:
            shown = first.decode("utf-8", "replace").strip()[:40]
            raise RunFolderError(
                f"{path} does not start with hrl-torch's header ({header.strip()[:40]}...; "
                f"found {shown!r}): it is not this run's log and no row is appended to it; "
                "restore it from a copy or move it away (the resume then starts a new one)"
            )
    path = run_dir / "hparams.json"
    if not path.exists():
        return None
    try:
        hparams = json.loads(path.read_text())
    except (UnicodeDecodeError, ValueError) as err:
        raise RunFolderError(
            f"{path} is not valid JSON ({' '.join(str(err).split())[:80]}): the run's settings "
            "record is damaged; restore it from a copy of the run"
        ) from None
    if not isinstance(hparams, dict):
        raise RunFolderError(
            f"{path} holds a JSON {type(hparams).__name__}, not the run's settings (an object): "
            "restore it from a copy of the run"
        )
    return hparams
