"""Damaged run folders and edited run records, then ``--resume`` / ``eval``: one line naming the
file or field and what to do, the folder unchanged; a full disk after training is one line
with the checkpoint kept; non-finite numbers never reach summary.json."""

import errno
import json
import shutil
from pathlib import Path

import pytest
import torch

from hrl_torch.runs import experiment
from hrl_torch.training.runlog import RunLogger
from tests.run_folders import refused_lines, the_run, train


def _replace_with_folder(path: Path) -> None:
    path.unlink()
    path.mkdir()


def _replace_with_file(path: Path) -> None:
    shutil.rmtree(path)
    path.write_text("not a folder")


DAMAGE = {  # what is done to the copy, and what the one line says
    "hparams.json not JSON": (lambda d: (d / "hparams.json").write_text("{oops"), "not valid JSON"),
    "hparams.json []": (lambda d: (d / "hparams.json").write_text("[]"), "holds a JSON list"),
    "progress.csv a folder": (lambda d: _replace_with_folder(d / "progress.csv"), "is a folder"),
    "tb a file": (lambda d: _replace_with_file(d / "tb"), "is a plain file where the run keeps a"),
    "eval_episodes.csv's first line garbage": (
        lambda d: (d / "eval_episodes.csv").write_text(
            "garbage\n" + (d / "eval_episodes.csv").read_text().split("\n", 1)[1]
        ),
        "does not start with hrl-torch's header",
    ),
    "progress.csv's header of another program": (
        lambda d: (d / "progress.csv").write_text("a,b\n1,2\n"),
        "does not start with hrl-torch's header",
    ),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_a_damaged_run_folder_is_one_line_and_changes_nothing(case, trained_run, tmp_path, capsys):
    damage, expected = DAMAGE[case]
    run_dir = tmp_path / "copy"
    shutil.copytree(trained_run, run_dir)
    damage(run_dir)
    for line in refused_lines(run_dir, capsys):
        assert line.startswith("hrl-torch: error: ") and expected in line, line
        assert str(run_dir) in line


RECORDS = {  # a field of the checkpoint's run record edited, and what the line says
    "envs_per_learner": ("abc", "envs_per_learner is 'abc', expected a whole number >= 1"),
    "device": ("cuda:7", "device is 'cuda:7', expected a device this machine has"),
    "seeds": ("0,1", "seeds is '0,1', expected a non-empty list of seeds"),
    "threshold": (float("nan"), "threshold is nan, expected a finite number or null"),
    "eval_every": (-3, "eval_every is -3, expected a whole number >= 0"),
}


@pytest.mark.parametrize("field", list(RECORDS))
def test_an_edited_run_record_is_refused_field_by_field(field, trained_run, tmp_path, capsys):
    value, expected = RECORDS[field]
    run_dir = tmp_path / "copy"
    shutil.copytree(trained_run, run_dir)
    state = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    state["run"][field] = value
    torch.save(state, run_dir / "checkpoint.pt")
    for line in refused_lines(run_dir, capsys):
        assert expected in line and "the checkpoint was edited or damaged" in line, line


def test_a_full_disk_while_writing_plots_is_one_line_and_keeps_the_checkpoint(
    tmp_path, capsys, monkeypatch
):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "x.png"))

    monkeypatch.setattr(experiment, "plot_curves", full)
    assert train(tmp_path) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("hrl-torch: failed: No space left on device writing x.png after "), line
    assert "checkpoint" in line and "is kept" in line
    run_dir = the_run(tmp_path)
    assert torch.load(run_dir / "checkpoint.pt", weights_only=True)["trainer"]["step"] > 0


def test_a_full_disk_while_writing_the_summary_is_one_line(tmp_path, capsys, monkeypatch):
    def full(self, summary):
        raise OSError(errno.ENOSPC, "No space left on device", str(self.run_dir / "summary.json"))

    monkeypatch.setattr(RunLogger, "write_summary", full)
    assert train(tmp_path) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "No space left on device writing summary.json" in line, line


def test_summary_json_stays_valid_json_and_names_what_was_not_finite(tmp_path):
    logger = RunLogger(tmp_path, [0, 1], {}, tensorboard=False)
    logger.write_summary(
        {"status": "finished", "per_seed": [{"final_eval_return": float("inf")}, {"x": 1.0}],
         "threshold": float("nan")}
    )  # fmt: skip
    text = (tmp_path / "summary.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    summary = json.loads(text)
    assert summary["per_seed"][0]["final_eval_return"] is None
    assert summary["not_finite"] == ["per_seed[0].final_eval_return (inf)", "threshold (nan)"]


def test_a_sparse_tensor_of_another_shape_is_one_line_on_eval_and_resume(
    trained_run, tmp_path, capsys
):
    run_dir = tmp_path / "copy"
    shutil.copytree(trained_run, run_dir)
    state = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    key = next(iter(state["trainer"]["learner"]))
    empty = torch.zeros(0, dtype=torch.int64)
    state["trainer"]["learner"][key] = {  # a packed table of 2**20 entries: fits, but not the run
        "__hrl_torch_sparse__": [2**20], "dtype": "float32",
        "fill": torch.tensor(0, dtype=torch.int32), "index": empty, "values": empty.int(),
    }  # fmt: skip
    torch.save(state, run_dir / "checkpoint.pt")
    for line in refused_lines(run_dir, capsys):
        assert line.startswith("hrl-torch: error: checkpoint does not fit this run: "), line
