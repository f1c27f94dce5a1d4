"""SIGINT and SIGTERM at every phase of a run: one line, a clean folder or a resumable one."""

import json
import os
import signal
from pathlib import Path

import pytest

import hrl_torch.common.checkpoint as checkpoint_module
import hrl_torch.runs.experiment as experiment
from hrl_torch.common.checkpoint import load_checkpoint
from hrl_torch.runs.cli import main
from hrl_torch.training.trainer import Trainer

SMALL = ["--seeds", "2", "--envs-per-seed", "4", "--eval-every", "200", "--eval-episodes", "3"]
CODE = {"SIGINT": 130, "SIGTERM": 143}


def train(out, *extra) -> int:
    args = ["train", "taxi", "--algo", "maxq-q", *SMALL, "--out", str(out), "--no-progress"]
    return main([*args, "--no-tensorboard", *extra])


def send(name: str) -> None:
    os.kill(os.getpid(), signal.Signals[name].value)


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM"])
def test_a_signal_after_the_folder_is_made_before_training_removes_it(
    name, tmp_path, capsys, monkeypatch
):
    build = experiment.build_trainer

    def build_then_signal(*args, **kwargs):
        trainer = build(*args, **kwargs)
        send(name)  # the folder exists, nothing is trained
        return trainer

    monkeypatch.setattr(experiment, "build_trainer", build_then_signal)
    assert train(tmp_path, "--steps", "400") == CODE[name]
    assert capsys.readouterr().err.strip().splitlines() == [
        f"hrl-torch: interrupted ({name})"
    ]
    assert not list(tmp_path.iterdir())  # no half-made folder


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM"])
def test_a_signal_during_the_final_evaluation_still_writes_the_checkpoint(
    name, tmp_path, capsys, monkeypatch
):
    evaluate = Trainer._evaluate_and_log

    def signal_in_final_evaluation(self):
        if self.step >= 400:
            send(name)
        evaluate(self)

    monkeypatch.setattr(Trainer, "_evaluate_and_log", signal_in_final_evaluation)
    assert train(tmp_path, "--steps", "400", "--eval-every", "0") == CODE[name]
    (run_dir,) = tmp_path.iterdir()
    assert load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["step"] >= 400
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["per_seed"][0]["final_eval_return"]
    assert f"hrl-torch: {name} at step " in capsys.readouterr().err


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM"])
def test_a_signal_after_the_last_checkpoint_still_writes_summary_and_plots(
    name, tmp_path, capsys, monkeypatch
):
    plot = experiment.plot_curves

    def signal_while_plotting(*args, **kwargs):
        send(name)
        return plot(*args, **kwargs)

    monkeypatch.setattr(experiment, "plot_curves", signal_while_plotting)
    assert train(tmp_path, "--steps", "400") == CODE[name]
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["signal_after_training"] == name
    assert (run_dir / "charts_eval_return.png").exists()
    assert capsys.readouterr().err.strip().splitlines() == [
        f"hrl-torch: {name} after training: checkpoint, summary and plots written"
    ]


def test_two_sigterms_during_a_checkpoint_write_leave_no_stale_tmp(tmp_path, monkeypatch, capsys):
    save, sent = checkpoint_module.torch.save, []

    def signals_mid_write(obj, path, *args, **kwargs):
        if Path(path).name == "checkpoint.pt.tmp" and not sent:  # the first write
            sent.append(True)
            send("SIGTERM")
            send("SIGTERM")  # both wait for the write (and count once)
        return save(obj, path, *args, **kwargs)

    monkeypatch.setattr(checkpoint_module.torch, "save", signals_mid_write)
    assert train(tmp_path, "--steps", "800", "--checkpoint-every", "200") == 143
    (run_dir,) = tmp_path.iterdir()
    assert not list(run_dir.glob("*.tmp"))
    assert load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["step"] > 0
    assert "hrl-torch: SIGTERM at step " in capsys.readouterr().err
