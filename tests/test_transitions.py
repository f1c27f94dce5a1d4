"""The transition schema (``execution.transitions``) is what the executor emits, key by key."""

import pytest
import torch

import agents  # noqa: F401  (registers the built-in domains)
from hrl_torch.execution.transitions import (
    LEVEL,
    LEVEL_KEYS,
    OPTIONAL,
    PRIMITIVE,
    PRIMITIVE_KEYS,
    TransitionSchemaError,
    check_transitions,
)
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer

# every condition of the schema: no optional keys (maxq), some (har), all with features and
# scores (hybrid, hpgrl: continuous actions), visited states (key-door), multi-agent rows
CASES = [
    ("taxi", "maxq-q"),
    ("small-agv", "har"),
    ("ship-steering-earlier", "hybrid"),
    ("taxi-fuel-earlier", "hpgrl"),
    ("key-door", "maxq-q"),
    ("two-taxi-earlier", "selfish"),
]


def _trainer(domain, algo):
    opts = RunOptions(seeds=[0, 1], envs_per_learner=2, progress=False, eval_episodes=0)
    return build_trainer(registry.get(domain), algo, opts)


@pytest.mark.parametrize(("domain", "algo"), CASES)
def test_every_batch_matches_the_declared_keys(domain, algo):
    torch.set_num_threads(1)
    trainer = _trainer(domain, algo)
    executor = trainer.executor
    for _ in range(6):
        trainer.train_step()
        check_transitions(trainer.agent.batch, executor.uses, executor.transition_sizes())


def test_the_schema_covers_every_condition():
    sizes = {"L", "F", "K"}
    seen = set()
    for domain, algo in CASES:
        trainer = _trainer(domain, algo)
        seen |= trainer.executor.uses | {d for d in sizes if trainer.executor.transition_sizes()[d]}
    assert seen >= OPTIONAL | sizes
    for keys in (LEVEL_KEYS, PRIMITIVE_KEYS):
        assert len(keys) == len({k.name for k in keys})


def test_a_missing_extra_or_misshaped_key_is_named():
    trainer = _trainer("small-agv", "har")
    trainer.train_step()
    executor = trainer.executor
    sizes, uses = executor.transition_sizes(), executor.uses
    batch = trainer.agent.batch.clone()
    del batch[LEVEL]["terminal"]
    batch[LEVEL]["surprise"] = torch.zeros(batch[LEVEL].batch_size)
    batch[PRIMITIVE]["state"] = batch[PRIMITIVE]["state"].float()
    with pytest.raises(TransitionSchemaError) as err:
        check_transitions(batch, uses, sizes)
    text = str(err.value)
    assert "level.terminal: missing" in text
    assert "level.surprise: not declared" in text
    assert "primitive.state: dtype torch.float32, declared long" in text
    assert "next_state" not in uses  # a key the executor was not asked for is missing
    with pytest.raises(TransitionSchemaError, match="level.next_state: missing"):
        check_transitions(trainer.agent.batch, uses | {"next_state"}, sizes)
