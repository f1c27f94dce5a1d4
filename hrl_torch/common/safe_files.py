"""Writing only a run folder's own files: no link followed, no folder of another kind used.

A run folder someone sent (or a copy made with ``cp -a``) may hold symbolic links: a
``hparams.json`` that points at ``~/.bashrc``, a ``tb/seed_0`` that points at another folder.
Writing through them would change files outside the run. Every file hrl-torch writes in a run
folder is opened here: without following a link at its name (``O_NOFOLLOW``), refused when it
is not a plain file or when another name shares it (a hard link), and truncated only after
that check. ``check_tree`` refuses a folder that holds any link before a run touches it, and
``replace_file`` writes a whole file atomically through a new temporary file.
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import IO

NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # (Windows has no symbolic-link flag)
_MODES = {
    "w": os.O_WRONLY | os.O_CREAT,  # truncated after the check, not by open
    "a": os.O_WRONLY | os.O_CREAT | os.O_APPEND,
    "a+": os.O_RDWR | os.O_CREAT | os.O_APPEND,
    "x": os.O_WRONLY | os.O_CREAT | os.O_EXCL,
}
ADVICE = "copy run folders with cp -rL, not cp -a"


class RunFolderError(ValueError):
    """A run folder, or a file in it, that is not what hrl-torch wrote (a link, a wrong kind)."""


def kind_of(mode: int) -> str:
    """``'a symbolic link'``, ``'a folder'``, ``'a plain file'`` or ``'a special file'``."""
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a folder"
    return "a plain file" if stat.S_ISREG(mode) else "a special file"


def _link_text(path: Path) -> str:
    try:
        return f" (to {os.readlink(path)})"
    except OSError:
        return ""


def open_own(path: str | Path, mode: str = "w", newline: str | None = None) -> IO:
    """Open ``path`` for writing (``w``, ``a``, ``a+``, ``x``; text) without following links.

    Raises:
        RunFolderError: ``path`` is a link, a folder, a special file or a hard-linked file.
    """
    path = Path(path)
    try:
        fd = os.open(path, _MODES[mode] | NOFOLLOW | getattr(os, "O_CLOEXEC", 0), 0o666)
    except OSError as err:
        if err.errno in (errno.ELOOP, errno.EMLINK):  # the name is a symbolic link
            raise RunFolderError(
                f"{path} is a symbolic link{_link_text(path)}, not a file of the run: "
                f"hrl-torch writes no file through a link ({ADVICE})"
            ) from None
        if err.errno == errno.EISDIR:
            raise RunFolderError(
                f"{path} is a folder where the run keeps a file: the run folder is damaged; "
                "move it away or restore the run from a copy"
            ) from None
        raise
    try:
        found = os.fstat(fd)
        if not stat.S_ISREG(found.st_mode):
            raise RunFolderError(
                f"{path} is {kind_of(found.st_mode)} where the run keeps a plain file: the run "
                "folder is damaged; move it away or restore the run from a copy"
            )
        if found.st_nlink > 1:
            raise RunFolderError(
                f"{path} shares its data with another name (a hard link, {found.st_nlink} "
                f"names): writing it would change the other file too ({ADVICE})"
            )
        if mode == "w":
            os.ftruncate(fd, 0)
        return os.fdopen(fd, "w" if mode == "x" else mode, newline=newline)
    except BaseException:
        os.close(fd)
        raise


def write_own(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` in place (``open_own``): no link followed."""
    with open_own(path, "w") as f:
        f.write(text)
    return Path(path)


def replace_file(path: str | Path, write: Callable[[IO], None], binary: bool = False) -> Path:
    """Write ``path`` whole and atomically: ``write(file)`` into a new ``path.tmp``, then rename.

    A link (or anything) at ``path.tmp`` is removed first, never written through; the rename
    replaces a link at ``path`` rather than its target. A failed write leaves ``path`` as it
    was and no ``.tmp``.
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    if tmp.is_symlink() or tmp.is_file():
        tmp.unlink()
    fd = os.open(tmp, _MODES["x"] | NOFOLLOW | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        with os.fdopen(fd, "wb" if binary else "w", newline=None if binary else "") as f:
            write(f)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def check_tree(folder: str | Path, kinds: Callable[[str], str | None]) -> None:
    """Refuse ``folder`` if anything in it is a link, a shared file or of the wrong kind.

    ``kinds(relative_posix_path)`` is ``'file'``, ``'folder'`` or ``None`` (either) for each
    entry. ``folder`` itself may be reached through a link (the user names it); nothing in
    it may be one.

    Raises:
        RunFolderError: naming the first entry that is wrong and what to do.
    """
    folder = Path(folder)
    for top, dirs, files in os.walk(folder, followlinks=False):
        for name in sorted(dirs) + sorted(files):
            path = Path(top) / name
            found = os.lstat(path)
            relative = path.relative_to(folder).as_posix()
            if stat.S_ISLNK(found.st_mode):
                raise RunFolderError(
                    f"{path} is a symbolic link{_link_text(path)}: a run folder holds no links, or "
                    f"a run would write outside it; refused ({ADVICE})"
                )
            want = kinds(relative)
            if stat.S_ISREG(found.st_mode) and found.st_nlink > 1:
                raise RunFolderError(
                    f"{path} shares its data with another name (a hard link): a run writing it "
                    f"would change the other file too ({ADVICE})"
                )
            is_dir = stat.S_ISDIR(found.st_mode)
            if (want == "file" and not stat.S_ISREG(found.st_mode)) or (
                want == "folder" and not is_dir
            ):
                raise RunFolderError(
                    f"{path} is {kind_of(found.st_mode)} where the run keeps "
                    f"{'a folder' if want == 'folder' else 'a plain file'}: the run folder is "
                    "damaged; move that entry away or restore the run from a copy"
                )
