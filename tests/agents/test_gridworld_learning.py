"""Learning checks on the two new gridworld domains with their measured defaults
(docs/defaults.md): only real learning reaches their near-optimal thresholds."""

import pytest

from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer


@pytest.mark.slow
@pytest.mark.parametrize("domain,algo", [("key-door", "maxq-q"), ("four-rooms", "maxq-q")])
def test_maxq_q_reaches_the_threshold_with_the_domain_s_defaults(domain, algo):
    import agents  # noqa: F401  (registers the domains)

    spec = registry.get(domain)
    opts = RunOptions(seeds=[0, 1, 2], progress=False, tensorboard=False)
    trainer = build_trainer(spec, algo, opts)
    untrained = trainer.evaluate()[0]
    threshold = trainer.config.threshold
    assert (untrained < threshold - 10).all(), untrained  # no policy before learning
    result = trainer.train()
    reached = [s for s in result.steps_to_threshold if s is not None]
    assert len(reached) >= 2, (result.steps_to_threshold, result.final_eval, threshold)
