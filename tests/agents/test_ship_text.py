"""The ``-text`` ship variants (agents/ship_text.py): they build, step, and follow Section 5.3."""

import math
from dataclasses import replace

import pytest
import torch

from agents.ship import DOMAIN, LOCAL_GOAL, LOCAL_START, SUBTASK_NAMES, ship_hierarchy
from agents.ship_text import (
    TEXT,
    Harmonic,
    HybridTextLearner,
    ShipSubtaskEnv,
    low_level_config,
    make_hybrid_text,
    make_subtask_learner,
)
from hrl_torch.agent import HierarchicalAgent
from hrl_torch.exploration import Greedy
from hrl_torch.rng import BatchRNG
from hrl_torch.sync_count import HostSyncCounter

TEXT_ALGOS = ("hybrid-text", "flat-pg-text", "actor-critic-text")


def test_harmonic_step_size_decays_as_assumption_5_3_asks():
    alpha = Harmonic(0.01, 100.0)
    assert alpha(0) == 0.01 and float(alpha) == 0.01
    assert alpha(100) == pytest.approx(0.005)
    values = [alpha(k) for k in range(0, 10_000, 10)]
    assert all(a > b for a, b in zip(values, values[1:], strict=False))
    # sum alpha_k diverges like log, sum alpha_k^2 converges
    assert sum(alpha(k) ** 2 for k in range(200_000)) < 0.01**2 * 100 * 1.01 + 1e-6
    with pytest.raises(ValueError, match="tau > 0"):
        Harmonic(0.01, 0.0)


def test_harmonic_on_a_device_clock_gives_the_float_values_without_a_read():
    alpha = Harmonic(0.0025, 2e6)
    for step in (0, 1, 7, 999, 5_000_000):
        with HostSyncCounter() as counter:
            value = alpha(torch.tensor(step))
        assert counter.total == 0
        assert value.dtype == torch.float64 and float(value) == alpha(step)


def test_low_level_rule_is_algorithm_3_as_written():
    cfg = low_level_config()
    assert cfg.online and cfg.beta == 1.0 and cfg.baseline == 0.0
    assert isinstance(cfg.alpha, Harmonic)
    other = low_level_config(replace(TEXT, pg_beta=0.95, pg_online=False))  # comparisons only
    assert not other.online and other.beta == 0.95


def test_subtask_env_starts_at_the_local_start_and_ends_on_goal_or_box():
    for subtask in (0, 1):
        env = ShipSubtaskEnv(subtask, [0, 1], 8)
        obs = env.reset()["observation"]
        assert torch.equal(obs[:, :2], LOCAL_START[subtask].expand(16, 2))
        assert obs[:, 2].std() > 10  # random headings
        # one row a step from its goal heading at it, one about to leave the box
        env.state[0] = torch.tensor([*(LOCAL_GOAL[subtask] - torch.tensor([0.0, 2.0])), 0.0, 0.0])
        env.state[1] = torch.tensor([1.0, 75.0, -90.0, 0.0])
        td = env.step(torch.zeros(16, 1))
        assert bool(td["success"][0]) and bool(td["terminated"][0])
        assert not bool(td["success"][1]) and bool(td["terminated"][1])
    with pytest.raises(ValueError, match="subtask"):
        ShipSubtaskEnv(2)


def test_low_level_updates_every_step_before_the_invocation_ends():
    learner = make_subtask_learner(0, 1)
    env = ShipSubtaskEnv(0, [0], 4)
    agent = HierarchicalAgent(learner.graph, learner, Greedy(), BatchRNG([0], 4, "t"), 4)
    action = agent.start(env.reset())
    td = env.step(action)
    assert not bool(td["terminated"].any())
    before = learner.theta.clone()
    agent.step(td)
    assert not torch.equal(before, learner.theta)  # line 16 at this step, not at the renewal


def test_epsilon_waits_for_the_low_level_then_divides_by_1_01_every_50_episodes():
    learner = make_hybrid_text(ship_hierarchy(TEXT.out_of_bounds_reward), 2)
    eps, monitor = learner.epsilon, learner.monitor
    assert monitor.trigger_rate == TEXT.trigger_rate
    eps.observe(torch.tensor([120, 120]), torch.tensor([False, False]))
    assert torch.allclose(eps.values(), torch.tensor([0.1, 0.1]))
    eps.observe(torch.tensor([0, 0]), torch.tensor([True, False]))
    eps.observe(torch.tensor([49, 49]), torch.tensor([False, False]))
    assert torch.allclose(eps.values(), torch.tensor([0.1, 0.1]))
    eps.observe(torch.tensor([1, 1]), torch.tensor([False, False]))
    assert torch.allclose(eps.values(), torch.tensor([0.1 / 1.01, 0.1]))
    eps.observe(torch.tensor([100, 100]), torch.tensor([False, False]))
    assert eps.values()[0].item() == pytest.approx(0.1 / 1.01**3)


def test_pretraining_hands_each_subtask_to_its_group():
    params = replace(TEXT, pretrain_episodes=2, pretrain_envs=2)
    learner = make_hybrid_text(ship_hierarchy(params.out_of_bounds_reward), 2, params)
    assert isinstance(learner, HybridTextLearner) and not bool(learner.pretrained)
    stats = learner.pretrain()
    assert bool(learner.pretrained) and set(stats) == set(SUBTASK_NAMES)
    for name in SUBTASK_NAMES:
        assert min(stats[name]["episodes"]) >= 2
        assert learner.pg.group_view(name, 1).abs().sum() > 0
    state = learner.state_dict()
    again = make_hybrid_text(ship_hierarchy(params.out_of_bounds_reward), 2, params)
    again.load_state_dict(state)
    assert bool(again.pretrained)  # a loaded checkpoint does not pretrain again


@pytest.mark.parametrize("algo", TEXT_ALGOS)
def test_text_variants_build_and_step(algo):
    spec = DOMAIN.algos[algo]
    graph = spec.make_graph()
    learner = spec.make_learner(graph, 1)
    env = DOMAIN.make_env([0], 4)
    agent = HierarchicalAgent(
        graph, learner, spec.make_exploration(spec.train), BatchRNG([0], 4, "t"), 4, spec.executor
    )
    action = agent.start(env.reset())
    for _ in range(5):
        action = agent.step(env.step(action))
    pg = learner.pg if isinstance(learner, HybridTextLearner) else learner
    assert math.isfinite(float(pg.theta.abs().sum()))
    assert spec.envs_per_learner == 64
