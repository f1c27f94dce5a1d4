"""``check_env`` passes every domain of the repository and names each broken rule of a bad env."""

import dataclasses

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from agents.taxi import taxi_hierarchy as make_graph
from agents.taxi import taxi_primitives
from envs.taxi import TaxiEnv
from hrl_torch.env.envcheck import EnvContractError, check_env
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Subtask
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, run_experiment


@pytest.mark.parametrize("name", registry.names())
def test_every_domain_keeps_the_contract(name):
    domain = registry.get(name)
    spec = next(iter(domain.algos.values()))

    def make(seeds, e):
        return domain.make_env(seeds, e, "torch", **spec.env_options)

    env = make([0], 2)
    graph = None if env.n_agents is not None else spec.make_graph()
    before = env.state_dict()
    check_env(env, graph, make_env=make, steps=32)
    after = env.state_dict()  # the check puts the env back where it was
    assert all(torch.equal(before[k], after[k]) for k in ("state",) if k in before)
    assert before["rng"] == after["rng"]


@pytest.mark.parametrize("name", ["trash", "two-taxi-earlier", "four-agv-earlier"])
def test_torchrl_checker_runs_on_multi_agent_envs(name):
    domain = registry.get(name)
    env = domain.make_env([0], 2, "torch")
    check_env(env, steps=8, torchrl=True)  # through MultiAgentTorchRLEnv


def test_torchrl_and_gymnasium_checkers_run_on_the_wrappers():
    check_env(TaxiEnv([0], 2), make_graph(), TaxiEnv, steps=8, torchrl=True, gymnasium=True)
    with pytest.raises(EnvContractError, match="gymnasium check_env: "):
        check_env(TaxiEnv([0], 2), make_env=StateOutOfRange, steps=2, gymnasium=True)


class RewardColumn(TaxiEnv):
    def _step_all(self, action):
        reward, duration, terminated = super()._step_all(action)
        return reward[:, None], duration, terminated


class FloatFlags(TaxiEnv):
    def _output(self, reward, duration, terminated, truncated, is_init):
        td = super()._output(reward, duration, terminated, truncated, is_init)
        td["terminated"] = terminated.float()
        return td


class RowOutOfRange(TaxiEnv):
    def _observe(self):
        fields = super()._observe()
        fields["passenger"] = fields["passenger"] + 1  # 1..5, declared 5 values
        return fields


class StateOutOfRange(TaxiEnv):
    def _observe(self):
        fields = super()._observe()
        fields["observation"] = fields["observation"] + 500
        return fields


class NoAutoReset(TaxiEnv):
    def step(self, action):
        td = super().step(action)
        td["is_init"] = torch.zeros_like(td["is_init"])
        return td


class NaNReward(TaxiEnv):
    def _step_all(self, action):
        reward, duration, terminated = super()._step_all(action)
        return reward.masked_fill(action == 4, float("nan")), duration, terminated


class GlobalRandom(TaxiEnv):
    """Draws from torch's global generator: not in its state, not per row."""

    def _reset_rows(self, mask):
        pick = torch.randint(len(self.starts), (self.batch_size,))
        self.state = torch.where(mask, self.starts[pick], self.state)


def global_random(seeds, e):
    return GlobalRandom(seeds, e)


BROKEN = {
    RewardColumn: "step 1: field 'reward' expected shape [2], found [2, 2] torch.float32",
    FloatFlags: "reset: field 'terminated' expected dtype torch.bool, found [2] torch.float32",
    RowOutOfRange: "field 'passenger' expected values in [0, 5), found 5 (env row ",
    NoAutoReset: "field 'is_init' expected True (the row ended at step ",
    NaNReward: "reward and duration expected finite (duration >= 0), found nan and 1.0",
    GlobalRandom: "field 'observation' differs when replayed from the same state_dict",
}


@pytest.mark.parametrize("cls", list(BROKEN), ids=lambda c: c.__name__)
def test_each_broken_rule_is_named(cls):
    torch.manual_seed(0)
    env = cls([0], 2, max_episode_steps=20)
    with pytest.raises(EnvContractError) as info:
        check_env(env, steps=64)
    assert any(BROKEN[cls] in f for f in info.value.failures), info.value.failures


def test_a_population_that_is_not_separate_runs_is_named():
    with pytest.raises(EnvContractError) as info:
        check_env(TaxiEnv([0], 2), make_env=global_random, steps=16)
    assert info.value.failures == [
        "step 0: field 'observation' differs when the same seed runs in a population"
    ]


def test_an_abstraction_returning_floats_is_named():
    prims = taxi_primitives()
    root = Subtask(
        "Root", [p.name for p in prims], n_states=500, abstract=lambda o: o["observation"].float()
    )
    graph = TaskGraph("Root", [root, *prims], n_actions=6)
    with pytest.raises(EnvContractError, match=r"'Root'.abstract returned torch.float32"):
        check_env(TaxiEnv([0], 2), graph, steps=4)


def test_run_experiment_checks_the_env_before_writing_anything(tmp_path):
    domain = registry.get("taxi")
    broken = dataclasses.replace(domain, name="broken-taxi")
    broken.make_env = lambda seeds, e, backend="torch": RewardColumn(seeds, e)
    opts = RunOptions(seeds=[0], envs_per_learner=2, steps=8, out=str(tmp_path), progress=False)
    with pytest.raises(EnvContractError, match=r"field 'reward' expected shape"):
        run_experiment(broken, "maxq-q", opts)
    assert not list(tmp_path.iterdir())
