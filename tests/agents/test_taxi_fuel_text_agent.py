"""taxi-fuel: the root over the text's 8,750 states, measured in reward per step."""

import math

import torch

from agents.taxi_fuel_text import DOMAIN, EVAL_HORIZON, fuel_aware_hierarchy, text_hierarchy
from envs.taxi_fuel_text import N_STATES, TaxiFuelTextEnv, encode
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.continuing import ThroughputEvaluator


def test_the_root_sees_the_taxis_location():
    g = text_hierarchy()
    assert g.node("Root").n_states == N_STATES == 8_750
    env = TaxiFuelTextEnv([0], 2)
    env.reset()
    env.state = torch.tensor([encode(0, 0, 1, 2, 6), encode(4, 4, 1, 2, 6)])  # only the square
    ctx = g.context(env.step(torch.tensor([6, 6])))  # Fillup away from F changes nothing
    root = g.index["Root"]
    assert int(ctx.abstract[0, root]) != int(ctx.abstract[1, root])
    assert g.node("Get").n_states == 125 and g.node("Refuel").n_states == 25


def test_registered_with_a_reward_per_step_evaluation():
    domain = registry.get("taxi-fuel")
    assert domain is DOMAIN and sorted(domain.algos) == ["hpgrl", "maxq-q", "maxq-q-fuel", "q"]
    evaluator = domain.make_evaluator(domain.algos["q"].train)
    assert isinstance(evaluator, ThroughputEvaluator)
    assert (evaluator.horizon, evaluator.burn_in, evaluator.scale) == (EVAL_HORIZON, 0, 1.0)
    assert domain.algos["q"].make_graph().node("Root").n_states == N_STATES


def test_greedy_reward_per_step_is_reward_over_steps():
    opts = RunOptions(
        seeds=[0, 1], steps=4_096, eval_every=0, envs_per_learner=16, eval_episodes=4,
        progress=False, tensorboard=False,
    )  # fmt: skip
    trainer = build_trainer(DOMAIN, "maxq-q", opts)
    trainer.train()
    rate, reward_rate = trainer.evaluate()
    assert torch.equal(rate, reward_rate)  # the metric is the reward, one time unit a step
    # every step of every row is an env step of time 1 (resets take none): rates lie
    # between the worst and the best reward of one step
    assert bool(((rate >= -20) & (rate <= 20)).all())
    train = trainer.evaluator.last_train["charts/reward_rate"]
    assert all(math.isfinite(v) and -20 <= v <= 20 for v in train)


def test_fuel_aware_nodes_tell_fuel_levels_apart():
    g = fuel_aware_hierarchy()
    env = TaxiFuelTextEnv([0], 2)
    env.reset()
    env.state = torch.tensor([encode(2, 2, 4, 1, 0), encode(2, 2, 4, 1, 9)])  # only the fuel
    ctx = g.context(env.step(torch.tensor([6, 6])))  # Fillup off F changes nothing
    for name in ("Get", "Put", "Navigate_G", "Navigate_F", "South"):
        node = g.index[name]
        assert int(ctx.abstract[0, node]) != int(ctx.abstract[1, node]), name
    refuel = g.index["Refuel"]
    assert int(ctx.abstract[0, refuel]) == int(ctx.abstract[1, refuel])
    sizes = {n: g.node(n).n_states for n in ("Put", "Navigate_R", "South", "Root")}
    assert sizes == {"Put": 1_400, "Navigate_R": 350, "South": 14, "Root": N_STATES}
