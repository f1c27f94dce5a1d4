"""Exact resume, parameterized over every registered domain and every algorithm of each.

For each ``(domain, algo)`` the trainer is built the way the CLI builds it
(``hrl_torch.runs.experiment.build_trainer`` with ``RunOptions``) with a budget of ``TOTAL`` env
steps per learner. One run trains ``HALF`` steps, is checkpointed mid-episode and mid-subtask
(asserted: Task-Stacks hold running subtasks with accumulated reward), and a *fresh* trainer
loads the checkpoint and trains to ``TOTAL``. Against one uninterrupted ``TOTAL``-step run,
bit for bit:

- every tensor of the learner's ``state_dict`` (and every buffer, persistent or not),
- the executor's state: Task-Stacks with their accumulated reward, discounted reward, time and
  steps, subtask statistics, last action and observation,
- every RNG stream (exploration, env, evaluation) and the rest of the trainer's state,
- the logged rows (raw values and ``progress.csv``, wall-clock ``perf/`` rows left out) and
  the ``TrainResult``;

and the fresh trainer right after loading equals the trainer that saved. The cases are read from
``hrl_torch.runs.registry`` at collection time, so a newly registered algorithm is covered.

A checkpoint that loses the executor's accumulated ``reward`` of running subtasks makes the
learners that read it diverge (RAR's per-subtask gains and tables on small-agv, HPGRL's
reward-to-go on taxi-fuel-earlier) and leaves the Task-Stacks different; hence the checkpoint must
fall inside running subtasks that have accumulated reward.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import struct

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.runlog import RunLogger
from tests.cases import pair_param

SEEDS = (0, 1)
E = 4  # envs per learner: the clock advances by E per batched step
HALF = 144  # env steps per learner before the checkpoint (36 batched steps)
TOTAL = 2 * HALF
EVAL_EVERY = HALF // 2  # a multiple of E: evaluations fall on HALF, so leg one's final
LOG_EVERY = HALF // 4  # evaluation is one the uninterrupted run also makes
EVAL_MAX_STEPS = 30  # episodic evaluation: cap per greedy episode
EVAL_HORIZON, EVAL_BURN_IN = 20, 5  # continuing tasks: short throughput evaluations

#: (domain, algo) -> reason, for registered entries that learn nothing (heuristic baselines):
#: skipped.
NON_LEARNING: dict[tuple[str, str], str] = {
    (domain, rule): "a dispatching rule learns nothing"
    for domain, rules in (
        ("four-agv-earlier", ("fcfs", "hqf", "nsf")),
        ("four-agv", ("fcfs", "hqf", "nsf", "fcfs-2s", "hqf-2s", "nsf-2s")),
    )
    for rule in rules
}
#: (domain, algo) -> reason, for learners whose state cannot change within this tiny budget;
#: every other case must change its learner after the checkpoint (else the case is vacuous).
#: (HAR and RAR do change: their gains start from a prior and every step costs gain * time.)
_NO_ASSEMBLY = "no assembly is delivered within the budget: every reward is 0, the tables stay 0"
STILL_IN_BUDGET: dict[tuple[str, str], str] = {
    (d, a): _NO_ASSEMBLY
    for d, algos in (
        ("agv", ("hdr", "rvi-q")),
        ("agv-ct", ("hdr", "rvi-q")),
        ("four-agv-earlier", ("q",)),
    )
    for a in algos
}
#: domain -> reason, for domains where no running subtask ever holds accumulated reward; every
#: other hierarchical case must checkpoint running subtasks with nonzero accumulated reward.
NO_RUNNING_REWARD: dict[str, str] = {
    d: "the only reward (+1 per assembly) comes with the Unload step that ends DA_i"
    for d in ("agv", "agv-ct", "four-agv-earlier")
}
NO_RUNNING_REWARD["four-agv"] = (
    "the only reward is the team's assemblies; none is delivered within the budget"
)


def _cases() -> list:
    cases = []
    for domain in registry.names():
        for algo in sorted(registry.get(domain).algos):
            reason = NON_LEARNING.get((domain, algo))
            marks = [pytest.mark.skip(reason=reason)] if reason else []
            cases.append(pair_param(domain, algo, *marks, id=f"{domain}-{algo}"))
    return cases


CASES = _cases()


class RecordingLogger(RunLogger):
    """A ``RunLogger`` (CSV only) that also keeps every logged value as it was."""

    def __init__(self, run_dir) -> None:
        super().__init__(run_dir, SEEDS, {}, tensorboard=False)
        self.rows: list[tuple] = []

    def log(self, step: int, per_seed: dict) -> None:
        for tag, values in per_seed.items():
            if not tag.startswith("perf/"):  # wall-clock throughput
                self.rows.append((step, tag, tuple(float(v) for v in values)))
        super().log(step, per_seed)


def _float_bits(x: float) -> str:
    return struct.pack("<d", x).hex()


def _progress_rows(logger: RunLogger) -> list[list[str]]:
    with open(logger.csv_path, newline="") as f:
        return [r for r in csv.reader(f) if not r[2].startswith("perf/")]


def make(domain: str, algo: str, logger: RunLogger):
    opts = RunOptions(
        seeds=SEEDS,
        envs_per_learner=E,
        steps=TOTAL,
        eval_every=EVAL_EVERY,
        eval_episodes=2,
        progress=False,
        tensorboard=False,
    )
    trainer = build_trainer(registry.get(domain), algo, opts, logger)
    # knobs RunOptions does not expose, shrunk for speed (the same for every run of a case)
    trainer.config.log_every = LOG_EVERY
    trainer.config.eval_max_steps = EVAL_MAX_STEPS
    if trainer.evaluator.continuing:
        trainer.evaluator.horizon, trainer.evaluator.burn_in = EVAL_HORIZON, EVAL_BURN_IN
        trainer.evaluator.horizon_time = None  # timed windows (event-driven envs): too long
    return trainer


def _bitwise_equal(a: torch.Tensor, b: torch.Tensor) -> bool:
    if a.is_floating_point():
        as_int = {2: torch.int16, 4: torch.int32, 8: torch.int64}[a.element_size()]
        return torch.equal(a.contiguous().view(as_int), b.contiguous().view(as_int))
    return torch.equal(a, b)


def assert_same(a, b, where: str) -> None:
    """``a`` and ``b`` (nested dicts / lists of tensors and numbers) are equal bit for bit."""
    if isinstance(a, dict):
        assert isinstance(b, dict), f"{where}: {type(b).__name__} instead of a dict"
        assert a.keys() == b.keys(), f"{where}: keys {sorted(a)} != {sorted(b)}"
        for k in a:
            assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b), f"{where}: {type(b).__name__} instead of {type(a).__name__}"
        for k, (x, y) in enumerate(zip(a, b, strict=False)):
            assert_same(x, y, f"{where}[{k}]")
        assert len(a) == len(b), f"{where}: {len(a)} entries != {len(b)}"
    elif torch.is_tensor(a):
        assert torch.is_tensor(b), f"{where}: {type(b).__name__} instead of a tensor"
        assert (a.dtype, a.shape) == (b.dtype, b.shape), (
            f"{where}: {a.dtype}{list(a.shape)} != {b.dtype}{list(b.shape)}"
        )
        if not _bitwise_equal(a, b):
            differ = a.ne(b) & ~(a.isnan() & b.isnan()) if a.is_floating_point() else a.ne(b)
            first = [int(i) for i in differ.nonzero()[0]] if differ.any() else "(signed zeros)"
            at = tuple(first) if isinstance(first, list) else ()
            detail = f"{a[at].item()} != {b[at].item()}" if at else first
            raise AssertionError(
                f"{where}: {int(differ.sum())} of {a.numel()} entries differ, "
                f"first at {first}: {detail}"
            )
    elif isinstance(a, float):
        assert isinstance(b, float) and _float_bits(a) == _float_bits(b), f"{where}: {a} != {b}"
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def same(a, b) -> bool:
    try:
        assert_same(a, b, "")
    except AssertionError:
        return False
    return True


def trainer_state(trainer) -> dict:
    """The trainer's checkpoint state without the wall clock."""
    state = trainer.state_dict()
    del state["train_seconds"], state["eval_seconds"]
    return state


def buffers(trainer) -> dict:
    """Every buffer of the learner, non-persistent ones included (the banks heads view)."""
    return {name: buf for name, buf in trainer.learner.named_buffers()}


def assert_checkpoint_inside_subtasks(trainer, domain: str) -> None:
    """The Task-Stacks hold state a checkpoint must carry: mid-episode, mid-subtask."""
    assert bool((trainer.episodes.length > 0).any()), "checkpoint at an episode boundary"
    s = trainer.executor.stack
    if trainer.executor.depth <= 2:  # a flat graph: the root's child is always a primitive
        return
    # level j < top - 1 records the running non-primitive child of level j
    level = torch.arange(s.steps.shape[1])
    running = (level[None, :] < s.top[:, None] - 1) & (s.steps > 0)
    assert bool(running.any()), "checkpoint at a subtask boundary: no running subtask"
    assert bool((s.time[running] > 0).all())
    if domain in NO_RUNNING_REWARD:
        return
    assert bool((s.reward[running] != 0).any()), (
        "no running subtask has accumulated reward: losing it on load would go unnoticed"
    )


@pytest.mark.parametrize("domain,algo", CASES)
def test_resumed_run_equals_uninterrupted_run(domain, algo, tmp_path):
    torch.set_num_threads(1)
    straight_log = RecordingLogger(tmp_path / "straight")
    straight = make(domain, algo, straight_log)
    straight_result = straight.train()
    assert straight.step == TOTAL

    first_log = RecordingLogger(tmp_path / "run")
    first = make(domain, algo, first_log)
    first.train(steps=HALF, run_dir=tmp_path / "run")  # writes run/checkpoint.pt
    assert first.step == HALF
    assert_checkpoint_inside_subtasks(first, domain)
    at_half = copy.deepcopy(trainer_state(first))
    half_tables = copy.deepcopy(first.learner.state_dict())

    resumed_log = RecordingLogger(tmp_path / "run")  # resumes into the same run folder (CLI)
    resumed = make(domain, algo, resumed_log)
    resumed.load(tmp_path / "run" / "checkpoint.pt")
    after_load = copy.deepcopy(trainer_state(resumed))
    resumed_result = resumed.train()
    assert resumed.step == TOTAL

    # the learner: every tensor of its state_dict, then every buffer
    assert_same(straight.learner.state_dict(), resumed.learner.state_dict(), "learner")
    assert_same(buffers(straight), buffers(resumed), "learner buffers")
    # the executor: Task-Stacks (accumulated reward, time, ...), statistics, action, observation
    assert_same(straight.executor.state_dict(), resumed.executor.state_dict(), "executor")
    # every random stream
    assert_same(straight.policy.rng.state_dict(), resumed.policy.rng.state_dict(), "explore rng")
    assert_same(straight.env.state_dict(), resumed.env.state_dict(), "env")
    # everything else a further continuation reads (eval env and rng, evaluator, curve, ...)
    assert_same(trainer_state(straight), trainer_state(resumed), "trainer")
    # what was logged, raw and in progress.csv
    assert_same(first_log.rows + resumed_log.rows, straight_log.rows, "logged rows")
    assert _progress_rows(resumed_log) == _progress_rows(straight_log), "progress.csv differs"
    assert any(tag.startswith("hrl/") for _, tag, _ in resumed_log.rows), (
        "the resumed leg logged no training metrics"
    )
    assert len(straight.curve) == TOTAL // EVAL_EVERY
    timing = {"train_seconds", "env_steps_per_second", "eval_seconds"}
    for f in dataclasses.fields(straight_result):
        if f.name not in timing:
            a, b = getattr(straight_result, f.name), getattr(resumed_result, f.name)
            assert_same(a, b, f"TrainResult.{f.name}")

    # the checkpoint round trip itself: the fresh trainer equals the one that saved
    assert_same(at_half, after_load, "loaded checkpoint")
    # and the case is not vacuous: the learner changed after the checkpoint
    if (domain, algo) in STILL_IN_BUDGET:
        return
    final_tables = resumed.learner.state_dict()
    for k in ("td_abs", "td_count"):  # diagnostics, zeroed at every log
        del half_tables[k], final_tables[k]
    assert not same(half_tables, final_tables), (
        f"{domain}/{algo} learned nothing after the checkpoint (see NON_LEARNING, STILL_IN_BUDGET)"
    )
