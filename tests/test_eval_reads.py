"""Greedy evaluation off the CPU reads the device every few steps, not every step (issue 27).

On the CPU a read costs nothing and the evaluation reads every step (rows still playing,
immediate checks). Elsewhere each read synchronises, so the evaluation agent's checks are
deferred (``hrl_torch.training.deferred.deferred_meanwhile``) and the loop reads every
``evaluation.READ_EVERY`` steps. ``devicecheck.off_cpu_rules`` gives the CPU the off-CPU
rules: the same numbers and records, far fewer reads, the same error messages.
"""

import contextlib

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.common.sync_count import HostSyncCounter
from hrl_torch.execution.executor import BadStepError
from hrl_torch.runs import devicecheck, registry
from hrl_torch.runs.devicecheck import counting_steps
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training import evaluation
from hrl_torch.training.evaluation import EvalEpisodes

CONFIGS = [
    ("taxi", "maxq-q", 200),  # episodic, tabulated (frozen values, compaction)
    pytest.param(  # episodic, policy gradient below (9 s: make test-all)
        "ship-steering-earlier", "hybrid", 200, marks=pytest.mark.slow
    ),
    ("small-agv", "har", 0),  # continuing (a throughput window)
    ("trash", "cooperative", 0),  # multi-agent, the broadcast's rounds
]


@pytest.fixture
def off_cpu_rules():
    """``set_rules(True)``: the rules an off-CPU device gets, on the CPU, to the test's end
    (``devicecheck.off_cpu_rules``, what ``hrl-torch check`` uses)."""
    with contextlib.ExitStack() as rules:

        def set_rules(on: bool) -> None:
            if on:
                rules.enter_context(devicecheck.off_cpu_rules())

        yield set_rules


def _trained(domain: str, algo: str, eval_max_steps: int, envs: int = 4, episodes: int = 20):
    opts = RunOptions(seeds=[0, 1], envs_per_learner=envs, eval_episodes=episodes)
    opts.progress = opts.tensorboard = False
    trainer = build_trainer(registry.get(domain), algo, opts)
    if eval_max_steps:
        trainer.config.eval_max_steps = eval_max_steps
    if trainer.evaluator.continuing:  # a short throughput window (the defaults: 100 + 500 steps)
        trainer.evaluator.horizon, trainer.evaluator.burn_in = 100, 20
    for _ in range(200 if envs == 4 else 400):
        trainer.train_step()
    return trainer


def _evaluate(trainer) -> tuple[list, object, int, int]:
    """Numbers, records, host reads and env steps of one evaluation."""
    with counting_steps(type(trainer.eval_env)) as steps, HostSyncCounter() as reads:
        numbers = [x.tolist() for x in trainer.evaluate()]
    return numbers, trainer.last_eval_records, reads.total, steps[0]


@pytest.mark.parametrize(("domain", "algo", "eval_max_steps"), CONFIGS)
def test_off_the_cpu_the_evaluation_reads_every_few_steps_and_finds_the_same(
    domain, algo, eval_max_steps, off_cpu_rules
):
    results = []
    for on in (False, True):
        off_cpu_rules(on)
        results.append(_evaluate(_trained(domain, algo, eval_max_steps)))
    (numbers, records, reads, steps), (numbers_off, records_off, reads_off, steps_off) = results
    assert numbers_off == numbers
    assert records is None or bool((records_off == records).all())
    assert reads >= 2 * steps  # (every step: the rows still playing, the checks)
    # off the CPU: a handful per READ_EVERY steps, and the set-up's few
    assert reads_off <= 6 * steps_off / evaluation.READ_EVERY + 12
    assert steps_off <= steps + evaluation.READ_EVERY  # (a read stops it within READ_EVERY)


def test_off_the_cpu_episodes_that_end_are_split_off_and_the_loop_stops(off_cpu_rules):
    """A taxi population that has learned: every episode ends (in 13 steps on average), rows
    are split off once half have finished and the loop stops within ``READ_EVERY`` steps of
    the CPU's."""
    results = []
    for on in (False, True):
        off_cpu_rules(on)
        results.append(_evaluate(_trained("taxi", "maxq-q", 200, envs=64, episodes=40)))
    (numbers, records, _, steps), (numbers_off, records_off, _, steps_off) = results
    assert bool((records["length"] < 100).all()) and steps < 100  # (every episode ended)
    assert numbers_off == numbers and bool((records_off == records).all())
    assert steps <= steps_off <= steps + evaluation.READ_EVERY


def test_off_the_cpu_a_nan_in_an_evaluation_raises_the_immediate_message(off_cpu_rules):
    off_cpu_rules(True)
    trainer = _trained("taxi", "maxq-q", 200)
    step_all = trainer.eval_env._step_all

    def nan_in_row_3(action):
        reward, duration, terminated = step_all(action)
        return reward.index_fill(0, torch.tensor([3]), float("nan")), duration, terminated

    trainer.eval_env._step_all = nan_in_row_3
    with pytest.raises(BadStepError, match=r"env row 3 returned reward nan and duration"):
        trainer.evaluate()
    # the training checks the evaluation set aside are back, and still latch
    assert trainer.graph.__dict__.get("deferred_ranges") in trainer.deferred
    assert trainer.eval_env.deferred_action is None
    trainer.eval_env._step_all = step_all
    trainer.train_step()
    assert trainer.evaluate()[0].isfinite().all()


def test_rows_that_end_between_reads_are_counted_at_the_next_read():
    episodes = EvalEpisodes(4, "cpu")
    no = torch.zeros(4, dtype=torch.bool)
    two_end = {"reward": torch.ones(4), "terminated": torch.tensor([1, 1, 0, 0]).bool()}
    two_end["truncated"] = no
    none_end = dict(two_end, terminated=no)
    assert episodes.add(two_end, two_end["reward"], "terminated", read=False) == 4  # (unread)
    assert episodes.add(none_end, none_end["reward"], "terminated", read=True) == 2
    assert episodes.now["return"].tolist() == [1.0, 1.0, 2.0, 2.0]
