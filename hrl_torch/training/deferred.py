"""Checks of a training step that read the device later (docs/bad-input.md, "When checks fire").

A step with no host read cannot raise the moment an env returns a NaN reward or is handed an
action outside its space. With deferral on (the trainer turns it on), the env and the executor
record each such check in a ``DeferredCheck``: a flag on the device and the first failing
step's rows, latched with ``torch.where`` (no read). ``raise_pending`` reads the flags and
raises the first check's error, with the same message an immediate check gives, at the
trainer's next host read: its log interval, an evaluation, a checkpoint, the end of ``train``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager

import torch

from hrl_torch.common.devices import DeferredCheck
from hrl_torch.env.batched import BatchedEnv
from hrl_torch.execution.executor import HierarchicalExecutor, SubtaskTimeoutError, bad_step_error
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.base import Learner

__all__ = ["DeferredCheck", "defer_checks", "defer_reads", "deferred_meanwhile", "raise_pending"]


def raise_pending(checks: Iterable[DeferredCheck | None]) -> None:
    """Raise the first latched failure among ``checks`` (one read for their flags per device)."""
    checks = [c for c in checks if c is not None]
    failed = set()
    for device in {c.bad.device for c in checks if c.bad is not None}:  # (one read each)
        latched = [c for c in checks if c.bad is not None and c.bad.device == device]
        flags = torch.stack([c.bad.any() for c in latched]).tolist()
        failed |= {id(c) for c, flag in zip(latched, flags, strict=True) if flag}
    for check in checks:
        if id(check) in failed:
            raise check.error()  # (its ``on_read`` runs inside)
        if check.on_read is not None:
            check.on_read()


def defer_checks(env, executor: HierarchicalExecutor, learner=None) -> list[DeferredCheck]:
    """Turn on deferral of ``env``'s action check and ``executor``'s bad-step and stuck checks.

    With ``learner``, the learners among its modules defer their own checks
    (``Learner.deferred_checks``: the policy-gradient learners' ring check).

    Returns the checks to pass to ``raise_pending``; their messages are the immediate ones'.
    """
    g = executor.graph

    def bad_step(row: int, saved: dict) -> Exception:
        return bad_step_error(g, row, saved["reward"], saved["tau"], saved["top"], saved["inst"])

    def stuck(row: int, saved: dict) -> Exception:
        level = int(saved["stuck"][row].nonzero()[0])
        return GraphError(
            f"subtask {g.names[int(saved['node'][row, level])]!r} has no available child in "
            f"env row {row} (every child is terminated, not initiable or masked)"
        )

    limit = executor.config.max_subtask_steps

    def timeout(row: int, saved: dict) -> Exception:
        level = int(saved["over"][row].nonzero()[0])
        path = g.instance_path(int(saved["inst"][row, level]))
        return SubtaskTimeoutError(
            f"subtask {g.names[int(saved['node'][row, level])]!r} ran {limit} primitive steps "
            f"without terminating (env row {row}, instance {path})"
        )

    def quiet_again() -> None:  # the guard's quiet window anew, at a read the trainer makes
        if executor.depth > 1 and not executor.static_guard:  # (else: no quiet window)
            # (an invocation's steps grow by at most one per step)
            longest = int(executor.stack.inv_steps[:, 1:].amax())
            executor.guard_quiet = max(limit - longest - 1, 0)

    def out_of_range(row: int, saved: dict) -> Exception:
        col = int(saved["cols"][row].nonzero()[0])
        return GraphError(
            f"{g.names[col]!r}.abstract returned {int(saved['abstract'][row, col])}, outside "
            f"[0, {g.nodes[col].n_states}) (env row {row})"
        )

    g.deferred_ranges = DeferredCheck(out_of_range)
    executor.deferred_bad = DeferredCheck(bad_step)
    executor.deferred_stuck = DeferredCheck(stuck)
    executor.deferred_timeout = DeferredCheck(timeout, on_read=quiet_again)
    checks = [executor.deferred_bad, executor.deferred_stuck, executor.deferred_timeout]
    checks.append(g.deferred_ranges)
    # a new executor's invocations have run no step: none reaches the guard for limit - 1
    executor.guard_quiet = max(executor.guard_quiet, limit - 1)
    if isinstance(env, BatchedEnv) and (
        env.n_actions is not None or type(env).defer_checks is not BatchedEnv.defer_checks
    ):  # (overrides of the env's own action check that skip ``BatchedEnv``'s keep checking
        # at once unless they defer their own, as the ship's does)
        checks.append(env.defer_checks())
    for module in () if learner is None else learner.modules():
        if isinstance(module, Learner):  # (a hybrid's parts each defer their own)
            checks += module.deferred_checks()
    return checks


def defer_reads(env, executor: HierarchicalExecutor) -> list[DeferredCheck]:
    """``defer_checks`` for a non-learning agent (a greedy evaluation's): no read per step.

    Its ``executor``'s subtask guard then runs every step too (``static_guard``: a mask).
    """
    executor.static_guard = True
    return defer_checks(env, executor)


@contextmanager
def deferred_meanwhile(env, executor: HierarchicalExecutor) -> Iterator[list[DeferredCheck]]:
    """``defer_reads`` of ``env`` and ``executor`` for the block (a greedy evaluation's agent).

    The graph is shared with the trainer's agent: its range check, latched by training steps,
    is put back after the block, and so is ``env``'s action check. (Deferring again inside the
    block, for a subset of the rows, is fine: each call makes new checks.)
    """
    ranges = executor.graph.__dict__.get("deferred_ranges")
    action = vars(env).get("deferred_action")
    try:
        yield defer_reads(env, executor)
    finally:
        executor.graph.deferred_ranges = ranges
        env.deferred_action = action
