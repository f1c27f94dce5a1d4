"""A small trained taxi run folder and the checks that damage a copy of it.

``tests/test_damaged_runs.py`` and ``tests/test_run_folder_safety.py`` share one trained run
(the ``trained_run`` fixture of ``tests/conftest.py``): each test copies it, spoils the copy,
and checks that ``train --resume`` and ``eval`` refuse it in one line and change nothing.
"""

from __future__ import annotations

from pathlib import Path

from hrl_torch.runs.cli import main

SMALL = ["--seeds", "2", "--envs-per-seed", "4", "--eval-every", "200", "--eval-episodes", "3"]


def train(out, algo="maxq-q", *extra) -> int:
    """``hrl-torch train taxi`` for 400 steps with a checkpoint every 200; the exit code."""
    return main(
        ["train", "taxi", "--algo", algo, *SMALL, "--out", str(out), "--no-progress",
         "--steps", "400", "--checkpoint-every", "200", *extra]
    )  # fmt: skip


def the_run(out) -> Path:
    """The one run folder under ``out``."""
    (run_dir,) = [p for p in Path(out).iterdir() if p.is_dir()]
    return run_dir


def snapshot(folder) -> dict:
    """Every file below ``folder`` and its bytes."""
    return {p: p.read_bytes() for p in Path(folder).rglob("*") if p.is_file()}


def refused_lines(run_dir: Path, capsys) -> list[str]:
    """``train --resume`` and ``eval`` of ``run_dir``: each exits 2 with one line on stderr.

    Returns the two lines; the folder's files are checked unchanged.
    """
    before, lines = snapshot(run_dir), []
    for command in (
        ["train", "--resume", str(run_dir / "checkpoint.pt"), "--steps", "800", "--no-progress"],
        ["eval", str(run_dir)],
    ):
        assert main(command) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        lines.append(line)
    assert snapshot(run_dir) == before
    return lines
