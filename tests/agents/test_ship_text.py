"""The ``-text`` ship variants (agents/ship_text.py): they build, step, and follow Section 5.3."""

import math
from dataclasses import replace

import pytest
import torch

from agents.ship import LOCAL_GOAL, LOCAL_START, SUBTASK_NAMES, ship_hierarchy
from agents.ship_domain import DOMAIN
from agents.ship_text import (
    TEXT,
    Harmonic,
    HybridTextLearner,
    ShipSubtaskEnv,
    low_level_config,
    make_hybrid_text,
    make_subtask_learner,
)
from hrl_torch.common.rng import BatchRNG
from hrl_torch.common.sync_count import HostSyncCounter
from hrl_torch.modules.exploration import Greedy
from hrl_torch.training.agent import HierarchicalAgent

TEXT_ALGOS = ("hybrid", "flat-pg", "actor-critic")


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


def test_low_level_rule_is_equation_5_2_with_beta_1_less_a_state_baseline():
    cfg = low_level_config()
    # beta = 1 (Equation 5.3); the cycle's sum at the renewal, where R_n - V(s_n) is known
    assert not cfg.online and cfg.beta == 1.0 and cfg.baseline == 0.0
    assert TEXT.pg_value_rate > 0 and TEXT.features == "bearing"
    assert isinstance(cfg.alpha, Harmonic)
    every_step = low_level_config(replace(TEXT, pg_online=True, pg_value_rate=0.0))
    assert every_step.online and every_step.beta == 1.0  # line 16 as written, for comparison
    other = low_level_config(replace(TEXT, pg_beta=0.95))  # comparisons only
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
    learner = make_subtask_learner(0, 1, replace(TEXT, pg_online=True, pg_value_rate=0.0))
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


def test_bearing_coder_tiles_the_heading_error_to_the_goal():
    from agents.ship import bearing, low_level_tile_coder
    from agents.ship_text import BearingTileCoder, subtask_coder

    coder, plain = BearingTileCoder(LOCAL_GOAL[0]), low_level_tile_coder()
    g = torch.Generator().manual_seed(0)
    state = torch.rand(64, 4, generator=g) * torch.tensor([150.0, 150.0, 360.0, 30.0])
    state -= torch.tensor([0.0, 0.0, 180.0, 15.0])
    error = state[:, 2] - bearing(state[:, :2], LOCAL_GOAL[0].expand(64, 2))
    mapped = torch.cat([state[:, :2], ((error + 180) % 360 - 180)[:, None], state[:, 3:]], 1)
    assert torch.equal(coder(state), plain(mapped))
    # heading straight at the goal from two places: the same heading tiles, other places
    at = torch.tensor([[40.0, 40.0, 45.0, 0.0], [140.0, 40.0, 0.0, 0.0]])
    assert not torch.equal(plain(at)[0], plain(at)[1]) and coder(at).shape == (2, 9)
    assert isinstance(subtask_coder(1, replace(TEXT, features="bearing")), BearingTileCoder)
    with pytest.raises(ValueError, match="features"):
        subtask_coder(0, replace(TEXT, features="polar"))


def _subtask_run(params, setup, steps=60):
    """``theta`` after ``steps`` steps of the diagonal subtask (2 envs, fixed streams)."""
    learner = make_subtask_learner(0, 1, params)
    setup(learner)
    env = ShipSubtaskEnv(0, [3], 2)
    agent = HierarchicalAgent(learner.graph, learner, Greedy(), BatchRNG([3], 2, "t"), 2)
    action = agent.start(env.reset())
    ended = 0
    for _ in range(steps):
        td = env.step(action)
        ended += int(td["terminated"].sum() + td["truncated"].sum())
        action = agent.step(td)
    return learner, ended


def test_state_baseline_with_a_constant_table_is_the_constant_baseline():
    # V(s) = c everywhere must give Equation 5.2 less b = c: PGConfig.baseline's rule
    c, tiny = -30.0, 1e-30
    base = replace(TEXT, pg_online=False, pg_alpha=0.05, pg_value_rate=0.0)
    const, n1 = _subtask_run(
        replace(base, pg_baseline=tiny), lambda m: m.reward_to_go_mean.fill_(c)
    )
    state, n2 = _subtask_run(
        replace(base, pg_value_rate=tiny), lambda m: m.value_table[:-1].fill_(c)
    )
    plain, _ = _subtask_run(base, lambda m: None)
    assert n1 == n2 > 0  # invocations ended, so both rules updated
    assert torch.allclose(const.theta, state.theta, atol=1e-5)
    assert not torch.allclose(plain.theta, state.theta, atol=1e-3)  # the baseline mattered


def test_state_baseline_learns_the_reward_to_go_and_needs_renewal_updates():
    params = replace(TEXT, pg_value_rate=0.5)
    learner, ended = _subtask_run(params, lambda m: None, steps=120)
    assert ended > 0
    first, _ = _subtask_run(params, lambda m: None, steps=2)
    assert first.theta.abs().sum() == 0  # nothing ended yet: no update before the renewal
    table = learner.value_table[:-1]
    assert (table < 0).sum() > 0 and table.max() <= 0  # -1 a step: every return so far < 0
    assert learner.value_table[-1] == 0  # the sentinel
    with pytest.raises(ValueError, match="pg_online=False"):
        make_subtask_learner(0, 1, replace(TEXT, pg_online=True, pg_value_rate=0.1))


def test_low_level_success_counts_the_executions_that_ended_on_their_own():
    from agents.ship_learners import ShipMonitor

    spec = DOMAIN.algos["hybrid"]
    graph = spec.make_graph()
    learner = spec.make_learner(graph, 1)
    assert not learner.monitor.count_cut
    every = ShipMonitor(graph, 1)  # today's count: a cut execution is a failure
    observe = learner.monitor.observe

    def both(batch):
        every.observe(batch)
        return observe(batch)

    learner.monitor.observe = both
    env = DOMAIN.make_env([0], 32)
    explore = spec.make_exploration(spec.train)
    agent = HierarchicalAgent(graph, learner, explore, BatchRNG([0], 32, "t"), 32, spec.executor)
    action = agent.start(env.reset())
    for _ in range(150):
        action = agent.step(env.step(action))
    ended = int(every.episodes.events.sum())
    pairs = zip(every.low, learner.monitor.low, strict=True)
    cut = sum(int(a.events.sum() - b.events.sum()) for a, b in pairs)
    assert ended > 0 and cut == ended  # each episode's end cuts the one running execution


def test_state_baseline_static_rows_match_the_compacted_rows():
    # off the CPU every ring is read with static shapes: the same sums
    def static(m):
        m.static_rows = True

    compact, n1 = _subtask_run(TEXT, lambda m: None, steps=120)
    dense, n2 = _subtask_run(TEXT, static, steps=120)
    assert n1 == n2 > 0 and compact.value_table.abs().sum() > 0
    assert torch.allclose(compact.theta, dense.theta, atol=1e-5)
    assert torch.allclose(compact.value_table, dense.value_table, atol=1e-4)
