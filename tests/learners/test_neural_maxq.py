"""MAXQ-Q with MLP completions (hrl_torch.learners.neural_maxq): batched, exact per seed, learns."""

import pytest
import torch

from agents.taxi import taxi_hierarchy
from envs.taxi import TaxiEnv
from hrl_torch.learners.neural_maxq import NeuralMaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.neural import StackedMLP, factored_features, one_hot_features
from hrl_torch.modules.schedules import Linear
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer

SEEDS = [3, 11, 42]


def make(seeds, envs=4, updates=2, **kw):
    graph = taxi_hierarchy()
    learner = NeuralMaxQLearner(
        graph, len(seeds), alpha=0.3, gamma=0.95, lr=0.01, hidden=(16,), updates=updates, **kw
    )
    config = TrainConfig(steps=10**9, eval_every=0, progress=False)
    return Trainer(
        TaxiEnv(seeds, envs),
        graph,
        learner,
        EpsilonGreedy(Linear(1.0, 0.1, 2000)),
        config,
        TaxiEnv([7] * len(seeds), 5),
    )


def per_learner(trainer, p):
    """Every tensor of the learner's state with a population dimension, learner ``p``'s."""
    state = trainer.learner.state_dict()
    n = trainer.learner.n_learners
    return {k: v[p].clone() for k, v in state.items() if v.dim() and v.shape[0] == n}


@pytest.mark.parametrize(
    ("tables", "seeds"),
    [((), SEEDS), (("Root",), SEEDS), pytest.param((), list(range(10)), marks=pytest.mark.slow)],
)
def test_population_equals_separate_runs_bit_for_bit(tables, seeds):
    together = make(seeds, tables=tables)
    together.train(steps=120 * 4)
    first = per_learner(together, 0)
    assert any(k.startswith("completion.w") for k in first)  # the networks' weights
    assert any(k.startswith("optimizer.m_") for k in first)  # Adam's moments
    assert any(k.endswith(".V") for k in first)  # the primitives' tables
    for p, seed in enumerate(seeds):
        alone = make([seed], tables=tables)
        alone.train(steps=120 * 4)
        mine = per_learner(together, p)
        for name, value in per_learner(alone, 0).items():
            assert torch.equal(value, mine[name]), (seed, name)
    fresh = per_learner(make(seeds, tables=tables), 0)
    assert any(not torch.equal(fresh[k], first[k]) for k in fresh)  # it learned something


@pytest.mark.parametrize("updates", [1, 3])
def test_ten_seeds_take_one_forward_per_evaluation_and_per_adam_step(updates, monkeypatch):
    calls = []
    forward = StackedMLP.forward

    def counted(self, table, units):
        calls.append(table.shape[0])
        return forward(self, table, units)

    monkeypatch.setattr(StackedMLP, "forward", counted)
    for seeds in ([0], list(range(10))):
        trainer = make(seeds, updates=updates)
        trainer.train_step()
        calls.clear()
        for _ in range(5):
            trainer.train_step()
        # each step: one forward for the values at s', one per Adam step; every call batched
        # over the whole population
        assert calls == [len(seeds)] * (5 * (1 + updates))


def test_a_tabular_root_over_neural_subtasks():
    """``tables=("Root",)``: the root's completions are a table, the rest networks."""
    from hrl_torch.modules.heads import TableHead
    from hrl_torch.modules.neural import NeuralCompletionHead

    trainer = make(SEEDS, tables=("Root",))
    heads = trainer.learner.heads
    assert isinstance(heads["Root"], TableHead) and isinstance(heads["Get"], NeuralCompletionHead)
    root_before = heads["Root"]["C"].clone()
    root_net_before = trainer.learner.completion.node_parameters(
        trainer.learner.plan.order.tolist().index(trainer.graph.index["Root"])
    )["b1"].clone()
    trainer.train(steps=150 * 4)
    assert not torch.equal(heads["Root"]["C"], root_before)  # the table learned
    root_pos = trainer.learner.plan.order.tolist().index(trainer.graph.index["Root"])
    # the root's (unused) network got no gradient: Adam left it where it was
    assert torch.equal(trainer.learner.completion.node_parameters(root_pos)["b1"], root_net_before)
    state = trainer.learner.state_dict()
    assert "heads.Root.C" in state and "completion.w0" in state


def test_save_load_resume_is_exact(tmp_path):
    straight = make(SEEDS)
    straight.train(steps=80 * 4)
    first = make(SEEDS)
    first.train(steps=40 * 4)
    first.save(tmp_path / "ckpt.pt")
    resumed = make(SEEDS)
    resumed.load(tmp_path / "ckpt.pt")
    resumed.train(steps=80 * 4)
    state = resumed.learner.state_dict()
    for k, v in straight.learner.state_dict().items():
        assert torch.equal(v, state[k]), k


def test_rows_of_one_learner_read_that_learners_networks():
    """``greedy_table``'s rows (all of one learner) take the general path: the same values."""
    trainer = make(SEEDS)
    trainer.train(steps=100 * 4)
    g, learner = trainer.graph, trainer.learner
    obs = g.table_observations
    n = obs.batch_size[0]
    owner = torch.arange(3).repeat_interleave(n)
    ctx = g.context(obs[torch.arange(n).repeat(3)], owner)
    learner.evaluate_checked(ctx)
    for p in range(3):
        alone = g.context(obs, torch.full((n,), p))
        learner.evaluate_checked(alone)
        for key in ("V", "Q"):
            block = ctx.values[key][p * n : (p + 1) * n]
            torch.testing.assert_close(alone.values[key], block, atol=1e-5, rtol=0)


def test_interleaved_rows_are_sorted_into_the_batched_forward(monkeypatch):
    """A multi-agent env's rows interleave the table sets: one batched forward, same values."""
    from hrl_torch.common.ops import row_layout

    trainer = make(SEEDS)
    trainer.train(steps=60 * 4)
    g, learner = trainer.graph, trainer.learner
    obs = g.table_observations
    n = obs.batch_size[0]
    major = g.context(obs[torch.arange(n).repeat(3)], torch.arange(3).repeat_interleave(n))
    learner.evaluate_checked(major)
    rows = torch.arange(3).repeat(n)  # 0, 1, 2, 0, 1, 2, ...
    layout = row_layout(rows)
    assert layout.blocks == 3 and layout.order is not None
    learner.know_rows(rows, layout)
    widths = []
    forward = StackedMLP.forward
    monkeypatch.setattr(
        StackedMLP, "forward", lambda self, t, u: widths.append(t.shape) or forward(self, t, u)
    )
    mixed = g.context(obs[torch.arange(n).repeat_interleave(3)], rows)
    learner.evaluate_checked(mixed)
    assert widths == [(3, n * learner.plan.order.numel())]  # each learner's own rows only
    for key in ("V", "Q"):
        back = mixed.values[key].view(n, 3, *mixed.values[key].shape[1:]).transpose(0, 1)
        assert torch.equal(back.reshape(major.values[key].shape), major.values[key])


def test_encodings():
    assert one_hot_features([3, 2]).squeeze(-1).tolist() == [[0, 1, 2], [0, 1, 2]]
    units = factored_features([125, 4], [(5, 5, 5), None])
    assert units.shape == (2, 125, 3)
    assert units[0, 37].tolist() == [1, 5 + 2, 10 + 2]  # 37 = (1 * 5 + 2) * 5 + 2
    assert units[1, 3].tolist() == [3, 3, 3]  # one-hot, repeated to the width
    with pytest.raises(ValueError, match=r"radices \(5, 5\) multiply to 25, not 125"):
        factored_features([125], [(5, 5)])


def test_bad_settings_are_refused_in_one_line():
    graph = taxi_hierarchy()
    with pytest.raises(ValueError, match="encoding must be 'onehot' or 'factored'"):
        NeuralMaxQLearner(graph, 1, encoding="tiles")
    with pytest.raises(ValueError, match="updates must be >= 1"):
        NeuralMaxQLearner(graph, 1, updates=0)
    with pytest.raises(Exception, match=r"radices: \['Nowhere'\] are not subtasks"):
        NeuralMaxQLearner(graph, 1, encoding="factored", radices={"Nowhere": (2,)})
    with pytest.raises(Exception, match=r"tables: \['North'\] are not subtasks"):
        NeuralMaxQLearner(graph, 1, tables=("North",))
    with pytest.raises(ValueError, match="hidden must be one or more positive widths"):
        NeuralMaxQLearner(graph, 1, hidden=())


def test_factored_encoding_trains():
    """The factored encoding (taxi location as row and column) builds, steps and moves."""
    radices = {"Get": (5, 5, 5), "Put": (5, 5, 4), **{f"Navigate_{t}": (5, 5) for t in "RGYB"}}
    trainer = make([0], updates=1, encoding="factored", radices=radices)
    learner = trainer.learner
    names = [learner.graph.names[t] for t in learner.plan.order.tolist()]
    units = learner.units.view(len(names), -1, 3)  # (nodes, their states, 3 digits)
    assert units[names.index("Get"), 37].tolist() == [1, 7, 12]  # taxi (1, 2), passenger 2
    assert units[names.index("Navigate_R"), 7].tolist() == [1, 7, 7]  # (1, 2), repeated
    before = trainer.learner.completion.b1.detach().clone()
    trainer.train(steps=30 * 4)
    after = trainer.learner.completion.b1.detach()
    assert torch.isfinite(after).all() and not torch.equal(before, after)


@pytest.mark.slow
def test_the_registered_configuration_reaches_the_threshold():
    """``taxi --algo maxq-q-mlp`` at its defaults: greedy return >= 7.5 on both seeds."""
    import agents  # noqa: F401
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    torch.set_num_threads(1)
    opts = RunOptions(seeds=[0, 1], progress=False, tensorboard=False, eval_episodes=100)
    trainer = build_trainer(registry.get("taxi"), "maxq-q-mlp", opts)
    result = trainer.train()
    assert min(result.final_eval) >= 7.5, result.final_eval


def test_tabular_subtasks_follow_dietterichs_rules_with_internal_completions():
    """Every subtask in ``tables``: the hand-computed MAXQ-Q numbers, ``C`` and ``C~``."""
    from tests.learners.test_hand_computed_targets import (
        ALPHA,
        GAMMA,
        STEPS,
        per_state_chain,
        reference_maxq,
    )
    from tests.learners.test_q_lambda_and_hh_exact import run

    graph, env = per_state_chain(internal_rewards=True)
    learner = NeuralMaxQLearner(graph, 1, alpha=ALPHA, gamma=GAMMA, tables=("Root", "Go2", "Go3"))
    run(graph, env, learner, STEPS, gamma=GAMMA)
    vr, c, ci = reference_maxq()
    h = learner.heads
    got = {
        "go2@1": (h["Go2"]["C"][0, 1, 0], h["Go2"]["C_int"][0, 1, 0]),
        "go3": (h["Go3"]["C"][0, 0, 0], h["Go3"]["C_int"][0, 0, 0]),
        "root@0": (h["Root"]["C"][0, 0, 0], h["Root"]["C_int"][0, 0, 0]),
    }
    for key, (external, internal) in got.items():
        assert abs(float(external) - c[key]) < 1e-5, (key, float(external), c[key])
        assert abs(float(internal) - ci[key]) < 1e-5, (key, float(internal), ci[key])
    for s in range(3):
        assert abs(float(h["Right"]["V"][0, s, 0]) - vr[s]) < 1e-5


def test_networks_learn_internal_completions_apart_from_external_ones():
    """With networks: ``Go2``'s pseudo reward of 3 enters its ``C~`` output, not its ``C``."""
    from tests.learners.test_hand_computed_targets import GAMMA, per_state_chain
    from tests.learners.test_q_lambda_and_hh_exact import run

    graph, env = per_state_chain(internal_rewards=True)
    learner = NeuralMaxQLearner(graph, 1, gamma=GAMMA, lr=0.05, hidden=8, updates=4)
    run(graph, env, learner, 7 * 20, gamma=GAMMA)
    pos = learner.plan.order.tolist().index(graph.index["Go2"])
    unit = learner.unit_rows(torch.tensor([pos]), torch.tensor([1]))
    with torch.no_grad():
        out = learner.completions(
            torch.tensor([[pos]]), unit[None], torch.zeros(1, dtype=torch.long)
        )
    external, internal = float(out[0, 0, 0]), float(out[0, 0, learner.width])
    assert abs(external) < 0.3 and abs(internal - GAMMA * 3.0) < 0.3, (external, internal)
