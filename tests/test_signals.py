"""SIGINT and SIGTERM at every phase of a run: one line, a clean folder or a resumable one."""

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
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
    assert capsys.readouterr().err.strip().splitlines() == [f"hrl-torch: interrupted ({name})"]
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
    assert summary["status"] == "interrupted" and summary["partial_eval"]
    # the cut evaluation is no final return: null in the JSON, named as not finite
    assert summary["per_seed"][0]["final_eval_return"] is None
    assert "per_seed[0].final_eval_return (nan)" in summary["not_finite"]
    assert f"hrl-torch: {name} at step " in capsys.readouterr().err
    monkeypatch.setattr(Trainer, "_evaluate_and_log", evaluate)
    # the budget is spent but the final evaluation was cut: resuming plays it and finishes
    ckpt = str(run_dir / "checkpoint.pt")
    assert main(["train", "--resume", ckpt, "--no-progress", "--no-tensorboard"]) == 0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished" and "partial_eval" not in summary
    state = load_checkpoint(ckpt)["trainer"]
    assert state["curve"][-1][0] == state["step"] >= 400


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


def _signal_inside_evaluation(monkeypatch, name: str, after: int) -> list[int]:
    """Send ``name`` at the ``after``-th greedy step of the first evaluation; count its steps."""
    make, steps = Trainer.evaluation_agent, []

    def counting_agent(self, *args, **kwargs):
        agent = make(self, *args, **kwargs)
        step = agent.step

        def counted(td):
            steps.append(self.step)
            if len(steps) == after:
                send(name)
            return step(td)

        agent.step = counted
        return agent

    monkeypatch.setattr(Trainer, "evaluation_agent", counting_agent)
    return steps


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM"])
def test_a_signal_inside_a_periodic_evaluation_ends_it_at_once_and_marks_it_partial(
    name, tmp_path, capsys, monkeypatch
):
    steps = _signal_inside_evaluation(monkeypatch, name, after=3)
    assert train(tmp_path, "--steps", "800", "--set", "eval_max_steps=100000") == CODE[name]
    assert len(steps) == 3  # no greedy step after the signal
    (run_dir,) = tmp_path.iterdir()
    assert load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["step"] == 200
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["interrupted_by"] == name
    assert summary["partial_eval"]["step"] == 200 and summary["partial_eval"]["signal"] == name
    with open(run_dir / "eval_episodes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and {(r["step"], r["partial"]) for r in rows} == {("200", "1")}
    assert any(r["truncated"] == "1" for r in rows)  # the unfinished episodes
    captured = capsys.readouterr()
    assert f"(partial: {name})" in captured.out + captured.err


def test_a_signal_inside_a_throughput_evaluation_keeps_the_last_full_window(
    tmp_path, capsys, monkeypatch
):
    steps = _signal_inside_evaluation(monkeypatch, "SIGTERM", after=5)
    args = ["train", "trash", "--algo", "cooperative", "--seeds", "1", "--envs-per-seed", "2"]
    args += ["--steps", "300", "--eval-every", "0", "--eval-episodes", "1", "--out", str(tmp_path)]
    assert main([*args, "--no-progress", "--no-tensorboard"]) == 143
    assert len(steps) == 5
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["partial_eval"]["step"] == 300 and summary["status"] == "interrupted"
    assert load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["step"] == 300


@pytest.mark.slow
def test_a_real_sigterm_in_a_minutes_long_final_evaluation_exits_143_within_5_s(tmp_path):
    """The command in its own process; four-AGV's greedy window is 60,000 event steps."""
    root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, "-m", "hrl_torch.runs.cli", "--project", str(root), "train"]
    cmd += ["four-agv", "--algo", "cooperative", "--seeds", "1", "--steps", "200"]
    cmd += ["--out", str(tmp_path), "--no-tensorboard"]  # progress on: the bar says "eval"
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    err: list[bytes] = []
    reader = threading.Thread(target=lambda: err.extend(iter(lambda: proc.stderr.read(1), b"")))
    reader.start()
    deadline = time.monotonic() + 180
    while b"eval:" not in b"".join(err) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)  # well inside the final evaluation
    assert proc.poll() is None, b"".join(err).decode()[-2000:]
    sent = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=60)
    took = time.monotonic() - sent
    reader.join(timeout=10)
    text = b"".join(err).decode()
    assert proc.returncode == 143, text[-2000:]
    assert took < 5.0, f"exited {took:.1f} s after SIGTERM"
    assert "hrl-torch: SIGTERM at step 224: checkpoint written" in text
    (run_dir,) = tmp_path.iterdir()
    assert load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["step"] == 224
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["partial_eval"]["signal"] == "SIGTERM"
