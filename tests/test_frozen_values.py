"""A greedy evaluation on a tabulated graph evaluates the frozen tables once per state and looks
the values up (``hrl_torch.training.agent.FrozenValues``, issue "Hot path"): the same records as
evaluating the learner at every step."""

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.agent import HierarchicalAgent

FREEZE = HierarchicalAgent.freeze_values
# partly trained (batched steps), two seeds with different tables
CASES = [("taxi", "maxq-q", 600), ("key-door", "q", 1500), ("four-rooms", "maxq-q", 400)]


def trained(domain: str, algo: str, steps: int, **options):
    opts = RunOptions(seeds=[0, 1], envs_per_learner=8, progress=False, **options)
    trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(steps):
        trainer.train_step()
    return trainer


def frozen_and_not(trainer, evaluate, monkeypatch):
    """``evaluate(trainer)`` with the values frozen, then evaluated per step."""
    frozen = []

    def spy(self, steps):
        frozen.append(FREEZE(self, steps))
        return frozen[-1]

    monkeypatch.setattr(HierarchicalAgent, "freeze_values", spy)
    with_lookup = evaluate(trainer)
    monkeypatch.setattr(HierarchicalAgent, "freeze_values", lambda self, steps: False)
    per_step = evaluate(trainer)
    assert frozen == [True]
    return with_lookup, per_step


@pytest.mark.parametrize("domain,algo,steps", CASES)
def test_frozen_values_give_the_records_of_evaluating_every_step(domain, algo, steps, monkeypatch):
    trainer = trained(domain, algo, steps, eval_episodes=40)
    a, b = frozen_and_not(trainer, lambda t: t.evaluate_episodes(), monkeypatch)
    for key in a.keys(include_nested=True, leaves_only=True):
        assert torch.equal(a[key], b[key]), key
    returns = a["return"].view(2, -1)
    assert not torch.equal(returns[0], returns[1])  # two learners that act differently


def test_a_continuing_evaluation_with_frozen_values_measures_the_same(monkeypatch):
    trainer = trained("small-agv", "har", 3000)
    (throughput, rate), (throughput_b, rate_b) = frozen_and_not(
        trainer, lambda t: t.evaluate(), monkeypatch
    )
    assert torch.equal(throughput, throughput_b) and torch.equal(rate, rate_b)
    assert float(throughput.max()) > 0


def test_only_a_non_learning_agent_on_a_tabulated_graph_freezes_within_its_budget():
    taxi = trained("taxi", "maxq-q", 0, eval_episodes=10)
    with pytest.raises(RuntimeError, match="learning agent"):
        taxi.agent.freeze_values(10**6)
    agent = taxi.evaluation_agent(taxi.eval_env, "eval-explore")
    # 2 learners x 500 states against an eighth of 20 rows x steps
    assert not agent.freeze_values(399)
    assert agent.freeze_values(400)
    fuel = trained("taxi-fuel-earlier", "maxq-q", 0, eval_episodes=10)  # not tabulated
    assert not fuel.evaluation_agent(fuel.eval_env, "eval-explore").freeze_values(10**6)


def test_frozen_values_hand_the_learner_every_observation_field(monkeypatch):
    trainer = trained("taxi", "maxq-q", 300, eval_episodes=20)
    base = type(trainer.learner)

    class ReadsTheObservation(base):  # a user's learner whose values read ctx.obs
        def evaluate(self, ctx):
            super().evaluate(ctx)
            passenger = ctx.obs["passenger"].float()[:, None, None]
            ctx.values["Q"] = ctx.values["Q"] + 0.01 * passenger * (ctx.obs["taxi_row"] == 0)[
                :, None, None
            ]

    monkeypatch.setattr(trainer.learner, "__class__", ReadsTheObservation)
    a, b = frozen_and_not(trainer, lambda t: t.evaluate_episodes(), monkeypatch)
    for key in a.keys(include_nested=True, leaves_only=True):
        assert torch.equal(a[key], b[key]), key
