"""Greedy evaluation stops stepping finished rows (issue "Hot path"): the records are the same
as stepping every row to the end, on every domain whose env can be cut to a subset of rows."""

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.agent import HierarchicalAgent

SUBSET = HierarchicalAgent.subset
# partly trained (batched steps): 84-91% of the greedy episodes end early, the rest loop
CASES = [("taxi", "maxq-q", 600), ("taxi", "maxq-q", 800), ("key-door", "q", 2000)]


def records(domain: str, algo: str, steps: int, compact: bool, monkeypatch):
    opts = RunOptions(seeds=[0, 1], envs_per_learner=16, eval_episodes=40, progress=False)
    trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(steps):
        trainer.train_step()
    cuts = []

    def counted(self, rows):
        cuts.append(int(rows.shape[0]))
        return SUBSET(self, rows)

    monkeypatch.setattr(HierarchicalAgent, "subset", counted)
    trainer.eval_env.subset_safe = compact
    return trainer.evaluate_episodes(), cuts


@pytest.mark.parametrize("domain,algo,steps", CASES)
def test_compacted_evaluation_equals_stepping_every_row(domain, algo, steps, monkeypatch):
    full, no_cuts = records(domain, algo, steps, False, monkeypatch)
    compacted, cuts = records(domain, algo, steps, True, monkeypatch)
    assert no_cuts == [] and cuts, "the evaluation was never compacted"
    assert cuts == sorted(cuts, reverse=True) and cuts[-1] < 80 // 4 + 1
    for key in full.keys(include_nested=True, leaves_only=True):
        assert torch.equal(full[key], compacted[key]), key
    assert bool(full["success"].any()) and not bool(full["success"].all())


def test_an_rng_subset_draws_what_its_rows_drew():
    from hrl_torch.common.rng import BatchRNG

    full = BatchRNG([3, 7], 5, "any")
    full.uniform()  # a counter that is not zero
    rows = torch.tensor([1, 4, 8])
    sub = full.subset(rows)
    assert torch.equal(sub.uniform(3), full.uniform(3)[rows])
    assert sub.counter == full.counter


def test_an_env_subset_steps_as_its_rows_did():
    from envs.key_door import KeyDoorEnv

    full = KeyDoorEnv([3, 7], 6, max_episode_steps=5)  # episodes end: resets draw numbers
    full.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(3):
        full.step(torch.randint(6, (12,), generator=gen))
    rows = torch.tensor([0, 5, 9, 11])
    sub = full.subset(rows)
    for _ in range(8):
        action = torch.randint(6, (12,), generator=gen)
        a, b = full.step(action), sub.step(action[rows])
        for key in a.keys():
            assert torch.equal(a[key][rows], b[key]), key


@pytest.mark.parametrize("domain,algo", [("taxi", "maxq-q"), ("key-door", "q")])
def test_evaluating_some_learners_gives_their_numbers_of_a_full_evaluation(domain, algo):
    opts = RunOptions(seeds=[0, 1, 2], envs_per_learner=16, eval_episodes=30, progress=False)
    trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(700):
        trainer.train_step()
    full = trainer.evaluate()
    full_steps = trainer.last_eval_steps.clone()
    some = trainer.evaluate(learners=[0, 2])
    for a, b in zip(full, some, strict=True):
        assert torch.equal(a[[0, 2]], b[[0, 2]]) and bool(b[1].isnan())
    assert torch.equal(full_steps[[0, 2]], trainer.last_eval_steps[[0, 2]])
    played = trainer.last_eval_records["length"].view(3, 30)
    assert bool((played[1] == 0).all()) and bool((played[[0, 2]] > 0).all())
    assert bool(trainer.evaluate(learners=[])[0].isnan().all())
    with pytest.raises(ValueError, match="learners must be indices"):
        trainer.evaluate(learners=[3])
