"""The sampled leaf-irrelevance check warns on a primitive whose one abstract state merges
rewards, and is silent on correct hierarchies."""

import warnings
from dataclasses import replace
from pathlib import Path

import pytest

import agents  # noqa: F401  (registers the domains)
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer

PLUGIN = Path(__file__).resolve().parents[1] / "examples" / "hrl-corridor"


def trained_warnings(domain, algo: str, steps: int) -> list[str]:
    spec = domain.algos[algo]
    train = replace(spec.train, steps=steps, eval_episodes=0, check_leaf_rewards=True)
    domain = replace(domain, algos={algo: replace(spec, train=train)})
    trainer = build_trainer(domain, algo, RunOptions(seeds=[0, 1], progress=False))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        trainer.train()
    return [str(w.message) for w in caught if "leaf irrelevance" in str(w.message)]


@pytest.fixture
def corridor(monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGIN))
    import hrl_corridor

    return hrl_corridor


def test_a_primitive_with_one_state_and_a_goal_bonus_is_reported(corridor):
    def one_state_moves() -> TaskGraph:
        graph = corridor.corridor_hierarchy()
        nodes = [
            Primitive(x.name, x.action) if x.is_primitive else x for x in graph.nodes
        ]  # Left and Right with one abstract state
        return TaskGraph("Root", nodes, n_actions=2)

    spec = replace(corridor.DOMAIN.algos["maxq-q"], make_graph=one_state_moves)
    domain = replace(corridor.DOMAIN, algos={"maxq-q": spec})
    found = trained_warnings(domain, "maxq-q", 2_000)
    assert found == [
        "leaf irrelevance: primitive 'Right' saw rewards from -1 to 10 in its abstract state 0 "
        "(learner 0); if its expected reward depends on the merged states, give it an "
        "abstraction that separates them"
    ]


def test_silent_on_correct_hierarchies(corridor):
    assert trained_warnings(corridor.DOMAIN, "maxq-q", 2_000) == []
    assert trained_warnings(registry.get("taxi"), "maxq-q", 4_000) == []
