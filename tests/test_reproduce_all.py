"""``scripts/reproduce_all.py``: one command for every part of docs/reproduction.md."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import reproduce_all  # noqa: E402

#: scripts docs/reproduction.md names that are analyses of a finished run or sweeps, not a part
NOT_PARTS = {
    "reproduce_all.py",  # this command itself
    "ship_low_level_check.py",  # reads a finished ship run
    "ship_leave_penalty.py",
    "ship_pretrain.py",
    "taxi_fuel_text_sweep_table.py",  # tabulates a sweep folder
    "taxi_fuel_text_greedy.py",  # reads a finished run
    "four_agv_where_time_goes.py",  # reads finished runs
    "four_agv_heuristics.py",  # the dispatching rules' reference numbers
    "trash_trace.py",  # the step-size study
    "two_taxi_races.py",  # reads finished runs
    "four_agv_text_variants.py",  # issue 33's one-change-at-a-time study (its rows)
}


def test_every_figure_script_of_the_reproduction_page_is_a_part():
    text = (ROOT / "docs" / "reproduction.md").read_text()
    named = set(re.findall(r"scripts/([a-z0-9_]+\.py)", text))
    parts = {p.script for p in reproduce_all.PARTS}
    assert named - NOT_PARTS <= parts, sorted(named - NOT_PARTS - parts)
    for part in reproduce_all.PARTS:
        assert (ROOT / "scripts" / part.script).exists(), part.script
    assert len({p.name for p in reproduce_all.PARTS}) == len(reproduce_all.PARTS)


@pytest.mark.parametrize("quick", [False, True])
def test_dry_run_lists_every_part_with_its_output_folder(quick, tmp_path):
    cmd = [sys.executable, str(ROOT / "scripts" / "reproduce_all.py"), "--dry-run"]
    cmd += ["--out", str(tmp_path)] + (["--quick"] if quick else [])
    lines = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.splitlines()
    assert [line.split(":")[0] for line in lines] == [p.name for p in reproduce_all.PARTS]
    for line, part in zip(lines, reproduce_all.PARTS, strict=True):
        args = part.quick if quick else part.full
        assert f"scripts/{part.script} {' '.join(args)}".rstrip() in line
        if part.out_flag:
            assert f"{part.out_flag} {tmp_path / part.name}" in line
    assert not list(tmp_path.iterdir())  # a dry run writes nothing


def test_a_part_that_fails_is_reported_and_the_times_table_written(tmp_path, monkeypatch):
    broken = reproduce_all.Part("broken", "nowhere", "taxi_relapse.py", (), ("--seeds", "x"), None)
    monkeypatch.setattr(reproduce_all, "PARTS", (broken,))
    assert reproduce_all.main(["--quick", "--out", str(tmp_path)]) == 1
    table = (tmp_path / "times.md").read_text()
    assert "| broken | nowhere |" in table and "exit 2" in table
    assert "invalid int value" in (tmp_path / "broken.md").read_text()
