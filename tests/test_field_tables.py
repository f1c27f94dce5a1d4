"""Field tables (``TaskGraph.tabulate_fields``): looked-up predicates, the same values as calls."""

from __future__ import annotations

import hashlib

import pytest
import torch
from tensordict import TensorDict

import agents  # noqa: F401 (registers the built-in domains)
from hrl_torch.env.multiagent_env import agent_rows
from hrl_torch.hierarchy import field_tables
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Primitive, Subtask
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer, field_sizes


def _trainer(domain: str, algo: str, tables: bool, monkeypatch, steps: int = 0):
    with monkeypatch.context() as m:
        if not tables:
            m.setattr(field_tables, "MIN_CALLS", 10**9)
        opts = RunOptions(
            seeds=[0, 1], envs_per_learner=2, progress=False, tensorboard=False, check_env=False
        )
        opts.eval_episodes = 0
        trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(steps):
        trainer.train_step()
    return trainer


def _digest(trainer) -> str:
    h = hashlib.sha256()
    for key, value in sorted(trainer.learner.state_dict().items()):
        h.update(key.encode())
        h.update(value.detach().contiguous().reshape(-1).view(torch.uint8).numpy().tobytes())
    h.update(trainer.agent.executor.stack.inst.numpy().tobytes())
    return h.hexdigest()


def _four_agv():
    """The four-AGV text graph, cooperative (a field-tabled one and a called one), its env."""
    make = registry.get("four-agv").algos["cooperative"].make_graph
    env = registry.get("four-agv").make_env([0, 1], 2, "torch")
    graph, plain = make(), make()
    graph.tabulate_fields(field_sizes(env))
    return graph, plain, env


def test_four_agv_nodes_are_looked_up_and_give_the_called_context():
    graph, plain, env = _four_agv()
    tables = graph.field_tables
    assert tables is not None and tables.n_tabulated == 22  # every node but the root
    assert graph.index["Root"] not in tables.nodes.tolist()  # (reads the others' codes)
    assert plain.field_tables is None
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    for _ in range(60):  # random actions: states the greedy agent would not reach
        rows = agent_rows(td)
        rows.set("others_U1", torch.randint(0, 729, (rows.batch_size[0],), generator=gen))
        a, b = graph.context(rows), plain.context(rows)
        for name in ("abstract", "terminated", "blocked", "available"):
            assert torch.equal(getattr(a, name), getattr(b, name)), name
        action = torch.randint(0, env.n_actions, (env.batch_size, env.n_agents), generator=gen)
        td = env.step(action)


@pytest.mark.slow
def test_training_with_field_tables_learns_the_same_tables(monkeypatch):
    with_tables = _trainer("four-agv", "cooperative", True, monkeypatch, steps=40)
    called = _trainer("four-agv", "cooperative", False, monkeypatch, steps=40)
    assert _digest(with_tables) == _digest(called)


def test_few_calls_saved_leave_the_graph_as_it_was(monkeypatch):
    trainer = _trainer("trash", "cooperative", True, monkeypatch)
    assert trainer.graph.field_tables is None  # (about 12 calls: a lookup costs as much)


def _small_graph() -> TaskGraph:
    nav = [
        Subtask(
            f"Go{t}",
            ["Left", "Right"],
            n_states=5,
            abstract=lambda o: o["pos"],
            terminated=lambda o, t=t: o["pos"] == t,
            child_mask=lambda o: torch.stack([o["pos"] > 0, o["pos"] < 4], -1),
        )
        for t in range(6)
    ]
    root = Subtask(
        "Root", [n.name for n in nav], n_states=7, abstract=lambda o: o["pos"] + o["extra"]
    )
    prims = [Primitive("Left", 0), Primitive("Right", 1)]
    return TaskGraph("Root", [root, *nav, *prims], n_actions=2)


def test_only_nodes_reading_sized_fields_are_tabulated_and_a_bad_field_is_named():
    graph = _small_graph()
    plain = _small_graph()
    assert graph.tabulate_fields({"pos": 5}) == 6  # the Go nodes; the root reads "extra"
    assert graph.tabulate_fields({"pos": 5}) == 6  # (idempotent)
    obs = TensorDict({"pos": torch.arange(5), "extra": torch.tensor([0, 1, 2, 0, 1])}, [5])
    a, b = graph.context(obs), plain.context(obs)
    for name in ("abstract", "terminated", "blocked", "available"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    bad = TensorDict({"pos": torch.tensor([1, 5]), "extra": torch.tensor([0, 0])}, [2])
    with pytest.raises(GraphError, match="'pos' is 5 in env row 1, outside \\[0, 5\\)"):
        graph.context(bad)


def test_field_sizes_of_a_multi_agent_env():
    sizes = field_sizes(_four_agv()[2])
    assert sizes["location"] == 100 and sizes["drop_off_1"] == 4 and sizes["agent"] == 4
