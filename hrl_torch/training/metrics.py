"""Training metrics: finished episodes per learner and the subtasks' statistics at each log."""

from __future__ import annotations

import torch

from hrl_torch.common.ops import entries
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.training.evaluation import counted_reward, succeeded


def ratio(num: torch.Tensor, den: torch.Tensor) -> list[float]:
    """``num / den`` per entry as a list (NaN where ``den`` is 0)."""
    return torch.where(den > 0, num / den.clamp_min(1), torch.nan).tolist()


def per_seed(counts: torch.Tensor, n_learners: int) -> torch.Tensor:
    """Counters per table set ``[sets, ...]`` summed per seed ``[P, ...]``.

    A multi-agent learner has a table set per seed and agent.
    """
    return counts.view(n_learners, -1, *counts.shape[1:]).sum(1)


def subtask_metrics(
    graph: TaskGraph, executor, learner, n_learners: int, skipped: bool, step: int = 0
) -> tuple[dict, torch.Tensor]:
    """Calls, mean duration, success and TD error of every subtask since the last log.

    Tags ``hrl/<subtask>/...`` and ``losses/<subtask>/td_error``; with ``skipped``
    (``on_bad_step="skip"``) also the bad env steps skipped so far; and the calls per seed.
    A learner with ``log_scalars(step)`` adds its own (the PG subtasks': returns, policy
    mean and spread, update norm, step size; ``hrl_torch.learners.pg_stats``).
    """
    stats, scalars = executor.stats, {}
    calls, ends = per_seed(stats.calls, n_learners), per_seed(stats.ends, n_learners)
    durations = per_seed(stats.durations, n_learners)
    successes = per_seed(stats.successes, n_learners)
    td_abs = per_seed(learner.td_abs, n_learners)
    td_count = per_seed(learner.td_count, n_learners)
    for k in graph.subtasks():
        name = graph.names[k]
        scalars[f"hrl/{name}/calls"] = calls[:, k].tolist()
        scalars[f"hrl/{name}/mean_duration"] = ratio(durations[:, k], ends[:, k])
        scalars[f"hrl/{name}/success"] = ratio(successes[:, k], ends[:, k])
        scalars[f"losses/{name}/td_error"] = ratio(td_abs[:, k], td_count[:, k])
    log_scalars = getattr(learner, "log_scalars", None)
    if log_scalars is not None:  # (one value per table set: summed per seed where they differ)
        for tag, values in log_scalars(step).items():
            scalars[tag] = values if len(values) == n_learners else _seed_means(values, n_learners)
    if skipped:  # bad env steps skipped so far
        scalars["charts/skipped_steps"] = per_seed(executor.skipped_steps, n_learners).tolist()
    return scalars, calls


def _seed_means(values: list[float], n_learners: int) -> list[float]:
    """Per-table-set values averaged per seed (a multi-agent learner's sets: seed-major)."""
    return torch.tensor(values).view(n_learners, -1).nanmean(1).tolist()


def reset_subtask_counters(executor, learner) -> None:
    """Zero the counters ``subtask_metrics`` reads."""
    executor.stats.reset()
    learner.td_abs.zero_()
    learner.td_count.zero_()


class EpisodeTracker:
    """Returns, lengths and successes of finished training episodes, per learner.

    The sums stay on the env's device and are read at each log.
    """

    def __init__(
        self,
        batch_size: int,
        n_learners: int,
        envs_per_learner: int,
        success_key: str,
        device,
        finite_only: bool = False,
    ) -> None:
        self.success_key = success_key
        self.finite_only = finite_only  # skipped bad steps add nothing to returns
        self.rows = torch.arange(batch_size, device=device) // envs_per_learner
        self.n_learners = n_learners
        self.ret = torch.zeros(batch_size, device=device)
        self.length = torch.zeros(batch_size, device=device)
        self.sums = torch.zeros(4, n_learners, device=device)  # episodes, return, length, wins

    def add(self, td) -> torch.Tensor:
        """Account one step of every row; returns the rows that took a real step ``[B]``."""
        f = entries(td)
        real = ~f["is_init"]
        self.ret += counted_reward(f, self.finite_only) * real
        self.length += real
        ended = ((f["terminated"] | f["truncated"]) & real).float()
        won = succeeded(f, self.success_key)
        values = torch.stack([ended, self.ret, self.length, won.float()])
        self.sums.index_add_(1, self.rows, values * ended)
        keep = 1 - ended
        self.ret *= keep
        self.length *= keep
        return real

    def flush(self) -> dict[str, list[float]]:
        """Mean return, length and success of the episodes finished since the last flush."""
        sums = self.sums.cpu()
        n = sums[0]
        out = {
            "charts/episode_return": ratio(sums[1], n),
            "charts/episode_length": ratio(sums[2], n),
            "charts/episode_success": ratio(sums[3], n),
        }
        self.sums.zero_()
        return out

    def state_dict(self) -> dict:
        """The running sums (checkpoints)."""
        return {"ret": self.ret.clone(), "length": self.length.clone(), "sums": self.sums.clone()}

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``."""
        now = {"ret": self.ret, "length": self.length, "sums": self.sums}
        for k, current in now.items():
            if state[k].shape != current.shape:
                raise ValueError(f"episode tracker {k!r} shape mismatch")
        device = self.rows.device
        self.ret, self.length, self.sums = (state[k].to(device).clone() for k in now)
