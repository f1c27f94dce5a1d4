"""Every user error of the CLI is one line on stderr and exit code 2, and nothing is written."""

import json
import os
from pathlib import Path

import pytest

from hrl_torch.runs.cli import main

BASE = ["train", "taxi", "--algo", "maxq-q", "--no-progress"]
CASES = {
    "--seeds 0": "argument --seeds: must be >= 1, got 0",
    "--seeds -1": "argument --seeds: must be >= 1, got -1",
    "--steps -5": "argument --steps: must be >= 1, got -5",
    "--envs-per-seed 0": "argument --envs-per-seed: must be >= 1, got 0",
    "--eval-every -1": "argument --eval-every: must be >= 0, got -1",
    "--checkpoint-every -1": "argument --checkpoint-every: must be >= 0, got -1",
    "--threshold nan": "argument --threshold: must be a finite number, got nan",
    "--seeds two": "argument --seeds: expected a whole number, got 'two'",
    "--backend gym": "'taxi' has no backend 'gym'; choose from ('torch', 'gymnasium')",
    "--device tpu9": "argument --device: not a torch device: 'tpu9'",
    "--device mps": "argument --device: mps: this torch build has no usable MPS device",
    "--seed-offset 4294967295 --seeds 2": (
        "seed 4294967296 is outside [0, 2**32): the random streams hash 32-bit seeds, so larger "
        "seeds would repeat smaller ones"
    ),
    "--envs-per-seed 10000000 --seeds 2": "2 seeds x 10000000 envs per seed = 20,000,000 env "
    "rows, more than 16,777,216 (each row keeps kilobytes of state: this machine would run out "
    "of memory); use fewer envs per seed",
    "--seed-offset 9223372036854775807": "seed 9223372036854775807 is outside [0, 2**32): the "
    "random streams hash 32-bit seeds, so larger seeds would repeat smaller ones",
}


@pytest.mark.parametrize("extra", list(CASES))
def test_bad_options(extra, tmp_path, capsys):
    code = main([*BASE, "--out", str(tmp_path / "runs"), *extra.split()])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"hrl-torch: error: {CASES[extra]}"]
    assert not list(tmp_path.iterdir())  # nothing written


def test_unknown_domain_and_algorithm(tmp_path, capsys):
    assert main(["train", "nope", "--algo", "x", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("hrl-torch: error: unknown domain 'nope'; ")
    assert main(["train", "taxi", "--algo", "x", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    choices = "['maxq-q', 'maxq-q-mlp', 'q', 'smdp-q']"
    assert err == f"hrl-torch: error: 'taxi' has no algorithm 'x'; choose from {choices}"
    assert not list(tmp_path.iterdir())


def test_the_collector_on_a_multi_agent_domain(tmp_path, capsys):
    """The collector path is single-agent: said before anything is built (it used to fail at the
    first step, inside TorchRL's specs)."""
    args = ["train", "trash", "--algo", "cooperative", "--collector", "--no-progress"]
    code = main([*args, "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [
        "hrl-torch: error: the collector path (--collector) is single-agent, and TrashEnv has 2 "
        "agents per row: train it without the collector (docs/collectors.md)"
    ]
    assert not (tmp_path / "runs").exists()
    # and from Python: build_trainer says the same
    import agents  # noqa: F401
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    opts = RunOptions(seeds=[0], collector=True, progress=False, tensorboard=False)
    with pytest.raises(ValueError, match=r"collector path \(--collector\) is single-agent"):
        build_trainer(registry.get("trash"), "cooperative", opts)


def test_missing_and_corrupt_checkpoints(tmp_path, capsys):
    missing = tmp_path / "nope" / "checkpoint.pt"
    assert main([*BASE, "--resume", str(missing)]) == 2
    assert capsys.readouterr().err.strip() == f"hrl-torch: error: no checkpoint at {missing}"
    assert not (tmp_path / "nope").exists()
    corrupt = tmp_path / "checkpoint.pt"
    corrupt.write_bytes(b"not a checkpoint")
    assert main([*BASE, "--resume", str(corrupt)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is corrupt or not a torch checkpoint" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


def test_missing_project_folder(capsys):
    assert main(["--project", "/nonexistent", "list"]) == 2
    assert capsys.readouterr().err.strip() == (
        "hrl-torch: error: --project /nonexistent: no such folder"
    )


def test_debug_shows_the_traceback():
    with pytest.raises(Exception, match="must be >= 1"):
        main([*BASE, "--seeds", "0", "--debug"])


def test_a_failed_start_removes_the_run_folder_it_made(tmp_path, monkeypatch, capsys):
    import hrl_torch.runs.experiment as experiment

    def broken(*args, **kwargs):
        raise RuntimeError("the env could not be built")

    monkeypatch.setattr(experiment, "build_trainer", broken)
    assert main([*BASE, "--out", str(tmp_path)]) == 1  # one line (docs/bad-input.md)
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("hrl-torch: error: RuntimeError: the env could not be built"), line
    assert not list(tmp_path.iterdir())
    with pytest.raises(RuntimeError, match="could not be built"):  # --debug: the traceback
        main([*BASE, "--out", str(tmp_path), "--debug"])
    assert not list(tmp_path.iterdir())


def test_sweep_errors_are_one_line_before_ray_starts(tmp_path, capsys):
    args = ["sweep", "taxi", "--algo", "maxq-q", "--out", str(tmp_path), "--grid"]
    assert main([*args, "alpha"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hrl-torch: error: ") and "'alpha'" in err[0]
    assert main([*args, "nope=1,2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]
    assert not list(tmp_path.iterdir())


def test_an_out_that_is_a_file_or_not_writable(tmp_path, capsys, monkeypatch):
    afile = tmp_path / "afile"
    afile.write_text("")
    assert main([*BASE, "--out", str(afile / "runs")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"hrl-torch: error: --out {afile / 'runs'}: {afile} is a file, not a folder"
    )
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: p != str(locked) and real_access(p, mode))
    assert main([*BASE, "--out", str(locked / "runs")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"hrl-torch: error: --out {locked / 'runs'}: {locked} is not writable"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "locked"]
    assert not list(locked.iterdir())


def test_out_that_is_empty_or_cannot_be_made(tmp_path, capsys):
    assert main([*BASE, "--out", ""]) == 2
    assert capsys.readouterr().err.strip() == (
        "hrl-torch: error: --out must name a folder, got an empty string"
    )
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main([*BASE, "--out", str(blocker / "runs")]) == 2
    assert capsys.readouterr().err.strip().endswith("is a file, not a folder")
    if os.path.isdir("/proc/self"):  # Linux: /proc says writable to root, and is not
        assert main([*BASE, "--out", "/proc/hrl-torch-x"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("hrl-torch: error: --out /proc/hrl-torch-x: ")


def test_run_options_refuse_what_the_cli_refuses():
    from hrl_torch.runs.experiment import RunOptions

    for bad, message in (
        ({"seeds": []}, "at least one seed"),
        ({"seeds": [0, 0]}, "distinct"),
        ({"seeds": [2**32]}, "outside"),
        ({"seeds": ["a"]}, "integers"),
        ({"eval_every": -5}, "eval_every must be an integer >= 0"),
        ({"steps": 0}, "steps must be an integer >= 1"),
        ({"out": " "}, "must name a folder"),
    ):
        with pytest.raises(ValueError, match=message):
            RunOptions(**bad)


def test_an_agents_module_in_the_working_folder_is_not_run(tmp_path):
    """``hrl-torch list`` (or ``eval .``) in a folder holding an ``agents.py`` runs none of it."""
    import subprocess
    import sys

    (tmp_path / "agents.py").write_text("raise SystemExit('the working folder agents.py ran')\n")
    done = subprocess.run(
        [sys.executable, "-m", "hrl_torch.runs.cli", "list"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env=os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    assert done.returncode == 0, done.stderr
    assert "taxi [built-in]" in done.stdout


FAULTY = """
from dataclasses import replace

import torch

from agents.taxi import DOMAIN as TAXI
from envs.taxi import TaxiEnv


class NaNAfter(TaxiEnv):
    def _step_all(self, action):
        reward, duration, done = super()._step_all(action)
        self.calls = getattr(self, "calls", 0) + 1
        if self.batch_size == 6 and self.calls > {after}:  # the training env only
            reward = torch.full_like(reward, float("nan"))
        return reward, duration, done


def make_env(seeds, envs_per_learner, backend="torch"):
    return NaNAfter(seeds, envs_per_learner)


DOMAIN = replace(TAXI, name="faulty", make_env=make_env, backends=("torch",))
"""


@pytest.mark.parametrize("after", [0, 100])
def test_an_env_fault_while_training_is_one_line_and_leaves_a_clear_folder(
    after, tmp_path, capsys, monkeypatch
):
    from hrl_torch.runs import registry
    (tmp_path / f"faulty_{after}.py").write_text(FAULTY.replace("{after}", str(after)))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    out = tmp_path / "runs"
    args = ["--domain-module", f"faulty_{after}", "train", "faulty", "--algo", "q", "--seeds", "2"]
    args += ["--envs-per-seed", "3", "--steps", "2000", "--out", str(out), "--no-progress"]
    assert main([*args, "--no-tensorboard"]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("hrl-torch: failed: ") and "nan" in line.lower(), line
    runs = list(out.iterdir())
    # (the NaN check is deferred, docs/bad-input.md "When checks fire": with after=0 it fires
    # at the first step's log read, after one batched step, so that run's folder stays too)
    if after == 0:
        summary = json.loads((runs[0] / "summary.json").read_text())
        assert summary["status"] == "failed" and summary["failed_at_step"] == 3
    else:  # trained: the folder stays, saying why, with its logs
        summary = json.loads((runs[0] / "summary.json").read_text())
        assert summary["status"] == "failed" and summary["failed_at_step"] > 0
        assert (runs[0] / "progress.csv").exists() and "no checkpoint was written" in line


def test_eval_of_a_run_trained_without_evaluation(tmp_path, capsys):
    args = ["train", "taxi", "--algo", "q", "--seeds", "2", "--steps", "200", "--eval-episodes"]
    assert main([*args, "0", "--out", str(tmp_path), "--no-progress", "--no-tensorboard"]) == 0
    (run_dir,) = tmp_path.iterdir()
    capsys.readouterr()
    assert main(["eval", str(run_dir)]) == 0  # plays DEFAULT_EVAL_EPISODES per seed
    assert "seed 0" in capsys.readouterr().out


def test_evaluate_without_an_eval_env_names_it():
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    opts = RunOptions(seeds=[0], envs_per_learner=2, eval_episodes=0, progress=False)
    trainer = build_trainer(registry.get("taxi"), "q", opts)
    with pytest.raises(ValueError, match="no evaluation env"):
        trainer.evaluate()


def test_a_learner_built_on_another_graph_is_named():
    from agents.taxi import taxi_hierarchy
    from agents.taxi_fuel import taxi_fuel_hierarchy
    from envs.taxi import TaxiEnv
    from hrl_torch.learners import MaxQLearner
    from hrl_torch.modules.exploration import Greedy
    from hrl_torch.training.trainer import Trainer

    learner = MaxQLearner(taxi_fuel_hierarchy(), 1)
    with pytest.raises(ValueError, match="the learner was built on another task graph"):
        Trainer(TaxiEnv([0], 2), taxi_hierarchy(), learner, Greedy())
    Trainer(TaxiEnv([0], 2), taxi_hierarchy(), MaxQLearner(taxi_hierarchy(), 1), Greedy())


def test_train_config_refuses_negative_intervals():
    from hrl_torch.training.config import TrainConfig

    for bad in ({"eval_every": -5}, {"steps": -1}, {"log_every": 0}, {"threshold": float("nan")}):
        with pytest.raises(ValueError, match="TrainConfig"):
            TrainConfig(**bad)
