"""A population of P learners equals P separate runs with the same seeds; save/resume is exact."""

import pytest
import torch

from agents.taxi import flat_graph, taxi_hierarchy
from envs.taxi import TaxiEnv
from hrl_torch.common.checkpoint import CheckpointError
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.schedules import Linear
from hrl_torch.modules.tables import TableBank
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer

SEEDS = [3, 11, 42]


def make(seeds, learner_cls=MaxQLearner, graph_fn=taxi_hierarchy, envs=4, eval_episodes=5):
    graph = graph_fn()
    learner = learner_cls(graph, len(seeds), alpha=0.3, gamma=0.95)
    env = TaxiEnv(seeds, envs)
    eval_env = TaxiEnv([7] * len(seeds), eval_episodes)
    config = TrainConfig(steps=10**9, eval_every=0, progress=False)
    return Trainer(
        env,
        graph,
        learner,
        EpsilonGreedy(Linear(1.0, 0.1, 2000)),
        config,
        eval_env,
        ExecutorConfig(record_visited=8),
    )


def tables(trainer, p):
    banks = {n: m for n, m in trainer.learner.named_modules() if isinstance(m, TableBank)}
    return {n: m.data[p].clone() for n, m in banks.items()}


@pytest.mark.parametrize(
    "learner_cls,graph_fn", [(MaxQLearner, taxi_hierarchy), (SMDPQLearner, flat_graph)]
)
def test_population_equals_separate_runs(learner_cls, graph_fn):
    together = make(SEEDS, learner_cls, graph_fn)
    together.train(steps=600 * 4)
    for p, seed in enumerate(SEEDS):
        alone = make([seed], learner_cls, graph_fn)
        alone.train(steps=600 * 4)
        for name, value in tables(alone, 0).items():
            assert torch.equal(value, tables(together, p)[name]), (seed, name)
        assert any((t != 0).any() for t in tables(together, p).values())


def test_save_load_resume_is_exact(tmp_path):
    straight = make(SEEDS)
    straight.train(steps=800 * 4)
    straight_eval = straight.evaluate()

    first = make(SEEDS)
    first.train(steps=400 * 4)
    first.save(tmp_path / "ckpt.pt")
    resumed = make(SEEDS)
    resumed.load(tmp_path / "ckpt.pt")
    resumed.train(steps=800 * 4)
    for k, v in straight.learner.state_dict().items():
        assert torch.equal(v, resumed.learner.state_dict()[k]), k
    for k, v in straight.executor.stack.state_dict().items():
        assert torch.equal(v, resumed.executor.stack.state_dict()[k]), k
    for a, b in zip(straight_eval, resumed.evaluate(), strict=True):
        assert torch.equal(a, b)


def test_corrupt_or_mismatched_checkpoint_changes_nothing(tmp_path):
    trainer = make(SEEDS)
    trainer.train(steps=100 * 4)
    before = {k: v.clone() for k, v in trainer.learner.state_dict().items()}
    step = trainer.step

    path = tmp_path / "ckpt.pt"
    trainer.save(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # truncated file
    with pytest.raises(CheckpointError, match="corrupt"):
        trainer.load(path)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError):
        trainer.load(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError):
        trainer.load(tmp_path / "missing.pt")

    other = make([1, 2])  # two learners: tables of another shape
    other.save(tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="does not fit"):
        trainer.load(tmp_path / "other.pt")
    assert trainer.step == step
    for k, v in trainer.learner.state_dict().items():
        assert torch.equal(v, before[k]), k
    trainer.train(steps=200 * 4)  # still trains


def test_evaluation_is_a_function_of_the_tables_alone():
    # untrained tables tie everywhere: the greedy choices are the tie-breaking draws, which must
    # restart with every evaluation, as the eval env's episodes do
    trainer = make([0, 1], SMDPQLearner, flat_graph, eval_episodes=20)
    trainer.config.eval_max_steps = 50
    first = trainer.evaluate()
    trainer.train(steps=40)
    trainer.learner.Q.data.zero_()
    second = trainer.evaluate()
    for a, b in zip(first, second, strict=True):
        assert torch.equal(a, b)
