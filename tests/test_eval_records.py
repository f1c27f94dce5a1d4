"""Evaluation a user can inspect: one record per greedy episode, in the API, the run folder and
``hrl-torch eval``; the records agree with the reported means."""

import json
from pathlib import Path

import pytest
import torch

from hrl_torch.runs.cli import main
from hrl_torch.runs.experiment import evaluate_run
from hrl_torch.training.runlog import read_episodes

ARGS = ["--seeds", "2", "--envs-per-seed", "32", "--eval-every", "6000", "--eval-episodes", "8"]


@pytest.fixture(scope="module")
def taxi_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    args = ["train", "taxi", "--algo", "maxq-q", *ARGS, "--steps", "12000", "--out", str(out)]
    assert main([*args, "--no-progress", "--no-tensorboard"]) == 0
    (run_dir,) = out.iterdir()
    return run_dir


def test_records_agree_with_the_reported_means(taxi_run):
    summary = json.loads((taxi_run / "summary.json").read_text())
    episodes = read_episodes(taxi_run)
    assert len(episodes) == 16 and {e["step"] for e in episodes} == {12000}
    assert [e["return"] for e in episodes] == sorted(e["return"] for e in episodes)
    for row in summary["per_seed"]:
        mine = [e for e in episodes if e["seed"] == row["seed"]]
        assert sorted(e["episode"] for e in mine) == list(range(8))
        mean = sum(e["return"] for e in mine) / 8
        assert mean == pytest.approx(row["final_eval_return"], abs=1e-4)
        assert sum(e["success"] for e in mine) / 8 == pytest.approx(row["final_eval_success"])
        assert sum(e["length"] for e in mine) / 8 == pytest.approx(row["final_eval_steps"])
    # the first evaluation is in the file too (at 6016: the clock moves 32 per batched step)
    assert len(read_episodes(taxi_run, step=6016)) == 16


def test_the_root_decisions_of_a_taxi_episode(taxi_run):
    """A successful taxi episode is Get then Put at the root, each once."""
    for e in read_episodes(taxi_run):
        if e["success"]:
            assert e["decisions"] == "Get Put", e
        assert e["start"].startswith("destination=") and " taxi_row=" in e["start"]


def test_the_api_returns_a_tensordict_and_writes_nothing(taxi_run):
    before = {p: p.read_bytes() for p in taxi_run.rglob("*") if p.is_file()}
    trainer, records = evaluate_run(taxi_run)
    assert records.batch_size == torch.Size([16])
    assert set(records.keys()) >= {"learner", "seed", "episode", "return", "length", "success"}
    assert records["learner"].tolist() == [0] * 8 + [1] * 8
    saved = {(e["seed"], e["episode"]): e["return"] for e in read_episodes(taxi_run)}
    again = {
        (int(s), int(k)): float(r)
        for s, k, r in zip(records["seed"], records["episode"], records["return"], strict=True)
    }
    assert again == pytest.approx(saved)  # evaluation is a function of the tables alone
    assert {p: p.read_bytes() for p in taxi_run.rglob("*") if p.is_file()} == before


def test_an_untrained_policy_s_episodes_are_truncated(tmp_path):
    args = ["train", "taxi", "--algo", "maxq-q", "--seeds", "1", "--envs-per-seed", "4"]
    args += ["--steps", "4", "--eval-episodes", "3", "--out", str(tmp_path)]
    assert main([*args, "--no-progress", "--no-tensorboard"]) == 0
    (run_dir,) = tmp_path.iterdir()
    episodes = read_episodes(run_dir)
    failed = [e for e in episodes if not e["success"]]
    assert failed and all(e["truncated"] and e["length"] == 200 for e in failed)


def test_hrl_torch_eval_prints_the_worst_episodes(taxi_run, capsys):
    assert main(["eval", str(taxi_run), "--worst", "3", "--episodes", "4"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[0] == "taxi / maxq-q at step 12000, greedy evaluation:"
    assert out[1].startswith("  seed 0: return ") and out[1].endswith("over 4 episodes")
    assert out[3] == "worst 3 episodes:" and len(out) == 7
    returns = [float(line.split("return ")[1].split(",")[0]) for line in out[4:]]
    assert returns == sorted(returns)
    assert main(["eval", str(taxi_run.parent / "nope")]) == 2
    assert "no checkpoint at" in capsys.readouterr().err
