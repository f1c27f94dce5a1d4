"""The small frictions of issue 35: progress bars only on a terminal, the evaluation time beside
the training time, ``TorchRLEnv``'s constructor in ``inspect.signature``."""

import inspect
import io
import json

import pytest

from hrl_torch.common import progress
from hrl_torch.runs.cli import main


class _Stderr(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def _train_with_progress(tmp_path, monkeypatch, tty: bool) -> tuple[str, str]:
    err = _Stderr(tty)
    monkeypatch.setattr("sys.stderr", err)
    argv = ["train", "taxi", "--algo", "maxq-q", "--seeds", "2", "--envs-per-seed", "8"]
    argv += ["--steps", "800", "--eval-every", "400", "--eval-episodes", "3"]
    assert main([*argv, "--out", str(tmp_path), "--no-tensorboard"]) == 0  # (progress on)
    return err.getvalue(), next(p for p in tmp_path.iterdir() if p.is_dir()).name


@pytest.mark.parametrize("tty", [False, True])
def test_progress_bars_are_drawn_on_a_terminal_only(tmp_path, monkeypatch, capsys, tty):
    err, _ = _train_with_progress(tmp_path, monkeypatch, tty)
    out = capsys.readouterr().out
    if tty:  # a bar redraws itself with carriage returns
        assert "\r" in err and "train" in err
    else:  # a log file: no debris, and still one line per evaluation
        assert "\r" not in err and "train:" not in err
    evals = [x for x in out.splitlines() if x.startswith("eval at step")]
    assert len(evals) == 2 and "\r" not in out


def test_on_terminal_reads_isatty():
    assert progress.on_terminal(_Stderr(True)) and not progress.on_terminal(_Stderr(False))
    assert not progress.on_terminal(object())  # (no isatty at all)


def test_the_digest_gives_the_evaluation_time_beside_the_training_time(tmp_path, capsys):
    argv = ["train", "taxi", "--algo", "maxq-q", "--seeds", "2", "--envs-per-seed", "8"]
    argv += ["--steps", "800", "--eval-every", "400", "--eval-episodes", "3", "--no-progress"]
    assert main([*argv, "--out", str(tmp_path), "--no-tensorboard"]) == 0
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert 0 < summary["eval_seconds"] < summary["wall_seconds"]
    assert summary["train_seconds"] + summary["eval_seconds"] <= summary["wall_seconds"]
    out = capsys.readouterr().out
    assert f"greedy evaluation {summary['eval_seconds']} s" in out
    assert f"in {summary['train_seconds']} s " in out


def test_the_torchrl_envs_show_their_constructors():
    from hrl_torch.env.torchrl_env import TorchRLEnv
    from hrl_torch.env.torchrl_multiagent import MultiAgentTorchRLEnv
    from hrl_torch.training.collector import AutoResetTorchRLEnv

    assert str(inspect.signature(TorchRLEnv)) == "(env: 'BatchedEnv')"
    assert str(inspect.signature(MultiAgentTorchRLEnv)) == "(env: 'MultiAgentBatchedEnv')"
    assert list(inspect.signature(AutoResetTorchRLEnv).parameters) == ["env", "stack", "resume"]


def test_every_seed_s_tensorboard_run_has_its_settings_in_the_hparams_tab(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams import plugin_data_pb2

    argv = ["train", "taxi", "--algo", "maxq-q", "--seeds", "2", "--envs-per-seed", "8"]
    argv += ["--steps", "400", "--eval-every", "400", "--eval-episodes", "2", "--no-progress"]
    argv += ["--set", "learner.alpha=0.25"]
    assert main([*argv, "--out", str(tmp_path)]) == 0
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    for seed in (0, 1):
        events = EventAccumulator(str(run_dir / "tb" / f"seed_{seed}"))
        events.Reload()
        content = events.PluginTagToContent("hparams")
        assert {"_hparams_/experiment", "_hparams_/session_start_info"} <= set(content)
        start = plugin_data_pb2.HParamsPluginData.FromString(
            content["_hparams_/session_start_info"]
        ).session_start_info
        values = {k: getattr(v, v.WhichOneof("kind")) for k, v in start.hparams.items()}
        assert values["seed"] == seed and values["train.steps"] == 400
        assert values["learner.class"] == "MaxQLearner" and values["envs_per_learner"] == 8
        experiment = plugin_data_pb2.HParamsPluginData.FromString(
            content["_hparams_/experiment"]
        ).experiment
        metrics = {m.name.tag for m in experiment.metric_infos}
        assert "charts/eval_return" in metrics and "charts/eval_return" in events.Tags()["scalars"]
