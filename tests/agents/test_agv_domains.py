"""The Chapter 4 domains: registration, every algorithm runs, the CLI writes per-seed throughput."""

import json

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from envs.agv import CAPACITY, AGVEnv
from hrl_torch.modules.tables import TableBank
from hrl_torch.runs import registry
from hrl_torch.runs.cli import main
from hrl_torch.runs.experiment import RunOptions, build_trainer


def test_chapter_4_domains_are_registered():
    assert {"small-agv", "agv", "agv-ct"} <= set(registry.names())
    assert sorted(registry.get("small-agv").algos) == ["har", "hdr", "hh", "maxq-q", "rar", "rvi-q"]
    for name in ("agv", "agv-ct"):
        assert sorted(registry.get(name).algos) == ["har", "hdr", "rar", "rvi-q"]


class PrimedAGV(AGVEnv):
    """The AGV env whose rows start with every buffer full: 2 assemblies waiting at each of
    P1-P3, 2 parts at each of D1-D3 (the machines blocked until an assembly is taken) and a
    part in each bay; then the usual arrivals. Deliveries are possible from the first steps,
    so a few hundred steps show what a learner made of them."""

    def _reset_rows(self, mask):
        super()._reset_rows(mask)
        m = mask[:, None]
        self.pick_up = torch.where(m, CAPACITY, self.pick_up)
        self.drop_off = torch.where(m, CAPACITY, self.drop_off)
        self.warehouse = torch.where(m, 1, self.warehouse)


SEEDS, ENVS, STEPS = [0, 1], 64, 400


def agv_trainer(domain, algo):
    # the registered configuration with the budget (and so the epsilon schedule) cut short
    opts = RunOptions(
        seeds=SEEDS,
        envs_per_learner=ENVS,
        eval_episodes=2,
        steps=ENVS * STEPS,
        progress=False,
        tensorboard=False,
    )
    trainer = build_trainer(registry.get(domain), algo, opts)
    trainer.env = PrimedAGV(SEEDS, ENVS, continuous=domain == "agv-ct")
    return trainer


def second_half_throughput(trainer) -> torch.Tensor:
    """Training throughput ``[P]`` of steps ``STEPS / 2 .. STEPS`` (exploration included)."""
    for k in range(STEPS):
        if k == STEPS // 2:
            trainer.evaluator.flush()
        trainer.train_step()
    return torch.tensor(trainer.evaluator.flush()["charts/throughput"])


_UNTRAINED: dict = {}


def untrained_throughput(domain, algo) -> torch.Tensor:
    """The baseline: the same trainer acting without updates (all tables 0, so every choice is
    uniform among the available children, whatever epsilon). It depends only on the domain
    and the graph, so HAR, RAR and HDR share one run (RVI-Q's flat graph has its own)."""
    key = (domain, registry.get(domain).algos[algo].make_graph)
    if key not in _UNTRAINED:
        trainer = agv_trainer(domain, algo)
        trainer.agent.learn = False
        _UNTRAINED[key] = second_half_throughput(trainer)
        assert trainer.learner.td_count.sum() == 0
    return _UNTRAINED[key]


#: each learner learns in the fast suite on one of the two domains, both domains run there (the
#: other four pairs, the same learners and envs, only in `make test-all`); that continuous time
#: changes nothing but the durations is checked exactly in tests/learners/test_average_reward.py
FAST_AGV = {("agv-ct", "har"), ("agv", "rar"), ("agv", "hdr"), ("agv", "rvi-q")}


@pytest.mark.parametrize(
    ("domain", "algo"),
    [
        pytest.param(d, a, marks=() if (d, a) in FAST_AGV else pytest.mark.slow, id=f"{a}-{d}")
        for d in ("agv", "agv-ct")
        for a in ("har", "rar", "hdr", "rvi-q")
    ],
)
def test_every_agv_algorithm_learns_something(domain, algo):
    # training throughput (assemblies per 1,000 steps / 1,000 s, the dissertation's curves)
    # over steps 200-400 of 64 primed rows per seed, against the untrained learner's on the
    # same rows; it must at least double. Measured (seeds 0, 1), untrained -> trained:
    #   agv:    HAR/RAR/HDR 4.6, 5.0 -> HAR 15.2, 23.3; RAR 13.4, 13.6; HDR 30.2, 28.7;
    #           RVI-Q 0.31, 0.94 -> 2.8, 5.6
    #   agv-ct: HAR/RAR/HDR 0.44, 0.55 -> HAR 2.5, 2.2; RAR 1.6, 1.4; HDR 3.0, 2.6;
    #           RVI-Q 0.03, 0.09 -> 0.28, 0.54
    # (for scale: the dispatching rule delivers 32.7 per 1,000 steps in the unprimed env)
    # Over 8 seeds (agv-ct) the ratio learned / untrained spreads widely: RAR 1.6-3.7 (median
    # 3.1), RVI-Q 1.7-4.8 (2.2), HAR 2.8-6.2 (4.5); the code before the core rewrite gave the
    # same spread (RAR 1.8-3.7, RVI-Q 1.1-9.0, HAR 0.9-5.8). So: every seed improves and the
    # two seeds at least double on average.
    # (no greedy check: with the optimistic gain prior the greedy policies of HAR and RAR
    # still loop on untried no-op choices this early, docs/reproduction.md)
    baseline = untrained_throughput(domain, algo)
    assert (baseline > 0).all()  # the random policy delivers some: the ratio means something
    trainer = agv_trainer(domain, algo)
    learned = second_half_throughput(trainer)
    assert learned.shape == (2,) and trainer.learner.td_count.sum() > 0
    ratio = learned / baseline
    assert (ratio > 1.2).all() and ratio.mean() > 2, (learned, baseline)
    banks = [m for m in trainer.learner.modules() if isinstance(m, TableBank)]
    assert all(torch.isfinite(b.store).all() for b in banks)
    assert trainer.learner.continuous == (domain == "agv-ct")
    trainer.evaluator.horizon, trainer.evaluator.burn_in = 30, 10
    throughput, rate = trainer.evaluate()
    assert throughput.shape == (2,) and torch.isfinite(throughput).all()


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
