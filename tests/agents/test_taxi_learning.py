"""Learning thresholds on taxi: only real learning passes them."""

import pytest

from agents.taxi import DOMAIN
from hrl_torch.runs.experiment import RunOptions, build_trainer

THRESHOLD = 7.5  # the optimal policy's expected return is 7.93
UNTRAINED = -150.0  # measured before training: -1,874 (MAXQ-Q), -327 (flat Q); they loop


def train(algo, **kw):
    opts = RunOptions(seeds=list(range(10)), progress=False, tensorboard=False, **kw)
    trainer = build_trainer(DOMAIN, algo, opts)
    untrained = trainer.evaluate()[0]
    assert (untrained < UNTRAINED).all(), untrained  # the baseline: no policy before learning
    return trainer.train()


def assert_learned(result, at_least=9):
    reached = [s is not None for s in result.steps_to_threshold]
    final_ok = [v >= THRESHOLD for v in result.final_eval]
    assert sum(reached) >= at_least, result.steps_to_threshold
    # still there at the end of training: no relapse into looping greedy policies
    assert sum(final_ok) >= at_least, result.final_eval


def test_maxq_q_reaches_the_threshold_on_the_batched_env():
    result = train("maxq-q", steps=60_000, eval_every=6_000)
    assert_learned(result)
    assert max(s for s in result.steps_to_threshold if s is not None) <= 60_000


@pytest.mark.slow
def test_maxq_q_reaches_the_threshold_on_gymnasium_taxi_v4():
    result = train(
        "maxq-q", backend="gymnasium", envs_per_learner=32, steps=60_000, eval_every=10_000
    )
    assert_learned(result)


@pytest.mark.slow
def test_flat_q_learns_too_but_needs_more_steps():
    flat = train("q", steps=300_000, eval_every=10_000)
    assert_learned(flat)
    maxq = train("maxq-q", steps=60_000, eval_every=2_048)
    median = sorted(s for s in maxq.steps_to_threshold if s is not None)[4]
    flat_median = sorted(s for s in flat.steps_to_threshold if s is not None)[4]
    assert median < flat_median
