"""The Chapter 4 domains: registration, every algorithm runs, the CLI writes per-seed throughput."""

import json

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch import registry
from hrl_torch.cli import main
from hrl_torch.experiment import RunOptions, build_trainer
from hrl_torch.tables import TableBank


def test_chapter_4_domains_are_registered():
    assert {"small-agv", "agv", "agv-ct"} <= set(registry.names())
    assert sorted(registry.get("small-agv").algos) == ["har", "hdr", "hh", "maxq-q", "rar", "rvi-q"]
    for name in ("agv", "agv-ct"):
        assert sorted(registry.get(name).algos) == ["har", "hdr", "rar", "rvi-q"]


@pytest.mark.parametrize("domain", ["agv", "agv-ct"])
@pytest.mark.parametrize("algo", ["har", "rar", "hdr", "rvi-q"])
def test_every_agv_algorithm_learns_something(domain, algo):
    opts = RunOptions(
        seeds=[0, 1], envs_per_learner=8, eval_episodes=2, progress=False, tensorboard=False
    )
    trainer = build_trainer(registry.get(domain), algo, opts)
    trainer.evaluator.horizon, trainer.evaluator.burn_in = 30, 10
    trainer.train(steps=8 * 150)
    banks = [m for m in trainer.learner.modules() if isinstance(m, TableBank)]
    assert all(torch.isfinite(b.store).all() for b in banks)
    assert trainer.learner.td_count.sum() > 0  # it made updates
    assert trainer.learner.continuous == (domain == "agv-ct")
    throughput, rate = trainer.evaluate()
    assert throughput.shape == (2,) and torch.isfinite(throughput).all()
    train = trainer.evaluator.flush()
    assert len(train["charts/throughput"]) == 2


def test_rvi_q_holds_the_full_agv_state_space_as_one_table():
    opts = RunOptions(
        seeds=[0], envs_per_learner=1, eval_episodes=0, progress=False, tensorboard=False
    )
    learner = build_trainer(registry.get("agv"), "rvi-q", opts).learner
    assert learner.Q.data.shape == (1, 1_347_192 * 5)


def test_cli_run_writes_per_seed_throughput(tmp_path, capsys):
    code = main(
        [
            "train",
            "small-agv",
            "--algo",
            "har",
            "--seeds",
            "2",
            "--steps",
            "1600",
            "--eval-every",
            "800",
            "--out",
            str(tmp_path),
            "--no-progress",
            "--no-tensorboard",
        ]
    )
    assert code == 0
    (run,) = tmp_path.iterdir()
    summary = json.loads((run / "summary.json").read_text())
    assert [r["seed"] for r in summary["per_seed"]] == [0, 1]
    for row in summary["per_seed"]:
        assert row["throughput_unit"].startswith("20 x part 1")
        assert row["final_eval_throughput"] >= 0 and row["final_train_throughput"] >= 0
        assert "final_eval_reward_rate" in row and "final_train_reward_rate" in row
    csv = (run / "progress.csv").read_text()
    assert "charts/eval_throughput" in csv and "charts/throughput" in csv
    assert (run / "charts_eval_throughput.png").exists()
