"""Continuing tasks: throughput (amount per unit of time) instead of episode returns.

A continuing task never ends an episode, so the ``Trainer``'s episodic evaluation (mean return
of greedy episodes) does not apply. ``ThroughputEvaluator`` gives the trainer two measures:

- **greedy throughput** (``evaluate``): every learner's current policy, chosen greedily with
  frozen tables, runs ``burn_in + horizon`` steps on the eval env from its reset state; the
  throughput is the metric summed over the last ``horizon`` steps of all the learner's eval
  rows divided by their total time. The eval env restarts its random stream each time (with
  one eval seed for all learners, as ``run_experiment`` sets up, every learner and every
  evaluation meets the same arrivals), so a curve measures changes of the policy.
- **training throughput** (``observe`` / ``flush``): the metric over the time the learner's
  training rows spent since the last log, exploration included: what an online system
  delivers while it learns (the dissertation's curves).

The metric is the reward by default; a domain may count something else (e.g. the small AGV's
weighted deliveries, ``20 * part1 + part2``). ``scale`` converts "per unit of time" into the
reported unit (e.g. per 10,000 steps). The greedy evaluation also reports the reward rate, the
gain of the greedy policy.

Wire it with ``Trainer(..., evaluator=ThroughputEvaluator(...))`` or a domain's
``DomainSpec.make_evaluator``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import torch
from tensordict import TensorDict

from hrl_torch.common.devices import static_shapes
from hrl_torch.common.ops import argmax_last
from hrl_torch.common.progress import progress_bar
from hrl_torch.common.signals import stop_requested
from hrl_torch.training.deferred import deferred_meanwhile, raise_pending
from hrl_torch.training.evaluation import Evaluator

Metric = Callable[[TensorDict], torch.Tensor]


def reward_metric(td: TensorDict) -> torch.Tensor:
    """The step's reward ``[B]``."""
    return td["reward"]


@dataclass
class ThroughputEvaluator(Evaluator):
    """Greedy and training throughput of every learner (see the module docstring).

    Attributes:
        horizon: steps of each greedy evaluation that count.
        burn_in: steps run first and not counted (from the reset state to steady behaviour).
        horizon_time: instead of a number of steps, count each row's steps that start within
            ``[burn_in_time, burn_in_time + horizon_time)`` of its time (event-driven envs,
            whose steps last from a millisecond to seconds); at most ``max_steps`` steps.
        burn_in_time: time run first and not counted (with ``horizon_time``).
        max_steps: cap on the steps of a timed evaluation.
        metric: amount of one step ``td -> [B]`` (default: the reward).
        scale: factor applied to amount per unit of time.
        unit: what the scaled throughput counts (for plot labels and the summary).
        tags: logged names of the greedy throughput and the greedy reward rate.
        train_tags: logged names of the training throughput and the training reward rate.
        ratio: optional ``(numerator, denominator)`` metrics whose sums' ratio is also
            reported (e.g. waiting time per delivered passenger), greedy and in training.
        ratio_tags: logged names of the greedy and the training ratio.
    """

    continuing: ClassVar[bool] = True

    horizon: int = 1_000
    burn_in: int = 100
    horizon_time: float | None = None
    burn_in_time: float = 0.0
    max_steps: int = 200_000
    metric: Metric = reward_metric
    scale: float = 1.0
    unit: str = "reward per unit of time"
    tags: tuple[str, str] = ("charts/eval_throughput", "charts/eval_reward_rate")
    train_tags: tuple[str, str] = ("charts/throughput", "charts/reward_rate")
    ratio: tuple[Metric, Metric] | None = None
    ratio_tags: tuple[str, str] = ("charts/eval_ratio", "charts/ratio")
    last_eval: dict[str, list[float]] = field(default_factory=dict, repr=False)
    last_train: dict[str, list[float]] = field(default_factory=dict, repr=False)
    _sums: torch.Tensor | None = field(default=None, repr=False)

    # ------------------------------------------------------------------ greedy
    @torch.no_grad()
    def evaluate(self, trainer) -> tuple[torch.Tensor, torch.Tensor]:
        """Greedy throughput and reward rate per learner ``([P], [P])`` on ``trainer.eval_env``."""
        env = trainer.eval_env
        if env is None:
            raise ValueError("a throughput evaluation needs an eval env (eval_episodes > 0)")
        if env.rng is not None:
            env.rng.load_state_dict({"counter": 0})
        agent = trainer.evaluation_agent(env, "eval-explore")
        n_steps = self.max_steps if self.horizon_time else self.burn_in + self.horizon
        agent.freeze_values(n_steps)  # the tables are frozen: values per state once
        action = agent.start(env.reset())
        if static_shapes(env.device):  # (a read synchronises: the checks wait for the reads)
            with deferred_meanwhile(env, agent.executor) as checks:
                sums = self._play(trainer, agent, env, action, n_steps, checks)
        else:
            sums = self._play(trainer, agent, env, action, n_steps, [])
        per_learner = sums.view(self._n_sums, -1, env.envs_per_learner).sum(-1).cpu()
        throughput, rate = _rates(per_learner, self.scale)
        if self.last_partial is None:  # (a window a signal cut short keeps the last full one)
            self.last_eval = {self.tags[0]: throughput.tolist(), self.tags[1]: rate.tolist()}
            if self.ratio is not None:
                self.last_eval[self.ratio_tags[0]] = _ratio(per_learner).tolist()
        return throughput, rate

    def _play(self, trainer, agent, env, action, n_steps: int, checks: list) -> torch.Tensor:
        """``[n_sums, B]``: the amounts of the window's steps (``checks`` read every 100).

        A signal (``signals.stop_requested``, polled every step) ends the window early and sets
        ``last_partial``: the sums then cover the steps played.
        """
        sums = torch.zeros(self._n_sums, env.batch_size, device=env.device)
        clock = torch.zeros(env.batch_size, device=env.device)  # each row's time so far
        end = self.burn_in_time + (self.horizon_time or 0.0)
        bar = progress_bar(
            trainer.config.progress, total=n_steps, desc="eval", unit="step", leave=False
        )
        self.last_partial = None
        for k in range(n_steps):
            self.last_partial = stop_requested()
            if self.last_partial is not None:
                break
            bar.update(1)
            td = env.step(action)
            if k % 100 == 99:
                raise_pending(checks)
            if self.horizon_time:  # the window is a span of time: count what starts in it
                count = (clock >= self.burn_in_time) & (clock < end)
                clock = clock + td["duration"]
                if k % 100 == 99 and bool((clock >= end).all()):
                    break
            else:
                count = torch.full_like(clock, k >= self.burn_in, dtype=torch.bool)
            sums += self._amounts(td) * count
            action = agent.step(td)
        bar.close()
        raise_pending(checks)
        return sums

    @property
    def _n_sums(self) -> int:
        return 3 if self.ratio is None else 5

    def _amounts(self, td: TensorDict) -> torch.Tensor:
        """``[n_sums, B]``: metric, reward, duration (and the ratio's two metrics)."""
        amounts = [self.metric(td), td["reward"], td["duration"]]
        if self.ratio is not None:
            amounts += [self.ratio[0](td), self.ratio[1](td)]
        return torch.stack([a.to(td["reward"].dtype) for a in amounts])

    # ------------------------------------------------------------------ training
    def observe(self, td: TensorDict, rows: torch.Tensor, n_learners: int) -> None:
        """Add one training step of every row (``rows [B]``: learner of each row)."""
        values = self._amounts(td) * (~td["is_init"]).float()
        if self._sums is None or self._sums.shape[1] != n_learners:
            shape = (self._n_sums, n_learners)
            self._sums = torch.zeros(shape, dtype=torch.float64, device=rows.device)
        self._sums.index_add_(1, rows, values.double())

    def flush(self) -> dict[str, list[float]]:
        """Training throughput and reward rate since the last flush, per learner."""
        if self._sums is None:
            return {}
        throughput, rate = _rates(self._sums.cpu(), self.scale)
        names = self.train_tags
        self.last_train = {names[0]: throughput.tolist(), names[1]: rate.tolist()}
        if self.ratio is not None:
            self.last_train[self.ratio_tags[1]] = _ratio(self._sums.cpu()).tolist()
        self._sums.zero_()
        return dict(self.last_train)

    def state_dict(self) -> dict:
        """The training sums since the last log (checkpoints)."""
        return {} if self._sums is None else {"sums": self._sums.clone()}

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``."""
        self._sums = state["sums"].clone() if "sums" in state else None

    def summary(self, learner: int) -> dict[str, float]:
        """Latest greedy and training throughput of one learner, for ``summary.json``."""
        out: dict = {"throughput_unit": self.unit}
        names = {
            self.tags[0]: "final_eval_throughput",
            self.tags[1]: "final_eval_reward_rate",
            self.train_tags[0]: "final_train_throughput",
            self.train_tags[1]: "final_train_reward_rate",
            self.ratio_tags[0]: "final_eval_ratio",
            self.ratio_tags[1]: "final_train_ratio",
        }
        for values in (self.last_eval, self.last_train):
            for tag, per_learner in values.items():
                out[names[tag]] = per_learner[learner]
        return out

    @property
    def units(self) -> dict[str, str]:
        """The greedy and the training throughput are in ``unit``."""
        return {self.tags[0]: self.unit, self.train_tags[0]: self.unit}

    @property
    def metrics(self) -> list[str]:
        """Every tag this evaluator logs (for plots)."""
        ratio = list(self.ratio_tags) if self.ratio is not None else []
        return [*self.tags, *self.train_tags, *ratio]


def _rates(sums: torch.Tensor, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(scale * amount / time, reward / time)`` from ``sums [3, P]`` (NaN without time)."""
    time = sums[2]
    safe = time.clamp_min(1e-12)
    throughput = torch.where(time > 0, scale * sums[0] / safe, torch.nan)
    rate = torch.where(time > 0, sums[1] / safe, torch.nan)
    return throughput.float(), rate.float()


def _ratio(sums: torch.Tensor) -> torch.Tensor:
    """``numerator / denominator`` of the ratio sums ``sums[3:5]`` (NaN without any)."""
    den = sums[4]
    return torch.where(den > 0, sums[3] / den.clamp_min(1e-12), torch.nan).float()


# ---------------------------------------------------------------------- learned policies
@torch.no_grad()
def greedy_table(learner, observations: TensorDict, learner_index: int = 0) -> torch.Tensor:
    """The greedy policy of one learner as an instance table ``[n_instances, max_states]``.

    ``observations`` holds every full state (e.g. a ``FiniteModel``'s); per instance and
    abstract state the child with the largest action value (the first full state of that
    abstract state decides; entries never met stay 0). The table runs in
    ``hrl_torch.analysis`` (``policy_gain``, ``TablePolicy``) for the exact gain of what was
    learned.
    """
    g = learner.graph
    n = observations.batch_size[0]
    rows = torch.full((n,), learner_index, dtype=torch.long)
    ctx = g.context(observations, rows)
    learner.evaluate_checked(ctx)
    table = torch.zeros(g.n_instances, int(g.node_n_states.max()), dtype=torch.long)
    for inst in range(g.n_instances):
        node = int(g.inst_node[inst])
        if bool(g.node_is_primitive[node]):
            continue
        q = learner.action_values(torch.full((n,), inst, dtype=torch.long), ctx)
        available = ctx.available[:, node]
        choice = argmax_last(torch.where(available, q, -torch.inf))
        state = ctx.abstract[:, node]
        first = torch.full((int(g.node_n_states[node]),), n, dtype=torch.long)
        first = first.scatter_reduce(0, state, torch.arange(n), "amin")
        seen = first < n
        table[inst, : len(first)][seen] = choice[first[seen]]
    return table
