"""Greedy evaluation: the ``Evaluator`` interface, episodic evaluation and its bookkeeping.

The ``Trainer`` asks its evaluator for one number per learner (and a second, e.g. the success
rate) at each evaluation, lets it see every training step and collects its metrics at each
log. Two evaluators exist: ``EpisodicEvaluator`` (mean return of greedy episodes, the default)
and ``hrl_torch.training.continuing.ThroughputEvaluator`` (continuing tasks: a throughput).
``EvalHistory`` keeps what the evaluations found (the curve, the first step at a threshold).

(A learner's own ``evaluate``, the values of its tables at a context, follows its
``hrl_torch.modules.eval_plan.EvalPlan``; this module evaluates policies.)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import ClassVar

import torch
from tensordict import TensorDict

from hrl_torch.common.devices import static_shapes
from hrl_torch.common.ops import entries
from hrl_torch.common.progress import progress_bar
from hrl_torch.common.signals import stop_requested
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.training.deferred import defer_reads, deferred_meanwhile, raise_pending
from hrl_torch.training.loops import LOOP_WINDOW, Loops, RecentStates, limit_note

__all__ = [
    "MAX_DECISIONS",
    "EpisodicEvaluator",
    "EvalEpisodes",
    "EvalHistory",
    "Evaluator",
    "counted_reward",
    "succeeded",
]

_STEP_FIELDS = ("reward", "duration", "terminated", "truncated", "is_init")
#: root decisions kept per evaluation episode
MAX_DECISIONS = 32


class Evaluator:
    """What the ``Trainer`` asks of an evaluator (subclass it; the defaults do nothing).

    Attributes:
        continuing: evaluates a continuing task (no episodes, no success rate).
        tags: logged names of the two numbers ``evaluate`` returns.
        metrics: the logged curves to plot.
        units: the unit of a plotted metric's axis, where its name does not say it.
        last_eval: further logged numbers of the latest evaluation (tag -> per learner).
        last_records: the latest evaluation's episodes (``None``: it plays none).
        last_loops: per episode of ``last_records``, the cycle of observations an episode that
            hit the step limit repeated (``hrl_torch.training.loops``; ``""`` for the others).
        last_steps: the latest evaluation's mean episode length per learner (``None``: none).
        last_partial: the signal (``"SIGTERM"``) that cut the latest evaluation short
            (``signals.stop_requested``), or ``None``: it ran to its end.
    """

    continuing: ClassVar[bool] = False
    tags: tuple[str, str] = ("charts/eval_return", "charts/eval_success")
    metrics: ClassVar[list[str]] = ["charts/eval_return", "charts/episode_return"]
    units: ClassVar[Mapping[str, str]] = MappingProxyType({})
    last_eval: Mapping[str, list[float]] = MappingProxyType({})
    last_records: TensorDict | None = None
    last_loops: list[str] | None = None
    last_steps: torch.Tensor | None = None
    last_partial: str | None = None

    def evaluate(self, trainer) -> tuple[torch.Tensor, torch.Tensor]:
        """Two numbers per learner ``([P], [P])`` for ``trainer``'s current tables."""
        raise NotImplementedError

    def observe(self, td: TensorDict, rows: torch.Tensor, n_learners: int) -> None:
        """See one training step of every row (``rows [B]``: learner of each row)."""

    def flush(self) -> dict[str, list[float]]:
        """Training metrics since the last log, per learner."""
        return {}

    def state_dict(self) -> dict:
        """What a checkpoint keeps of this evaluator."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``."""

    def summary(self, learner: int) -> dict[str, float]:
        """What ``summary.json`` adds for one learner."""
        return {}

    def limit_note(self) -> str:
        """What the progress line adds about the latest evaluation's episodes (``""``: none)."""
        return ""


class EpisodicEvaluator(Evaluator):
    """Mean return and success rate of one greedy episode per eval-env row (the default)."""

    def evaluate(self, trainer, learners=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Greedy episodes on ``trainer.eval_env``: mean return and success rate ``[P]``.

        ``learners``: only these learners' episodes are played (``episodes``); the others'
        numbers are NaN. A signal (``signals.stop_requested``) ends the episodes within one
        step; ``last_partial`` then names it and the unfinished episodes count as truncated.
        """
        records, self.last_partial, loops = _episodes(trainer, learners)
        self.last_records, self._loops = records, loops
        n = trainer.eval_env.envs_per_learner
        means = [
            records["length"].view(-1, n).mean(1),
            records["success"].float().view(-1, n).mean(1),
            records["return"].view(-1, n).mean(1),
        ]
        if learners is not None:
            skipped = ~_learner_mask(learners, trainer.P)
            means = [m.masked_fill(skipped, float("nan")) for m in means]
        self.last_steps = means[0]
        return means[2], means[1]

    _loops = None

    @property
    def last_loops(self) -> list[str] | None:
        """Per episode of ``last_records``, the cycle it repeated if it hit the step limit."""
        return None if self._loops is None else list(self._loops)

    @staticmethod
    def episodes(trainer, learners=None) -> TensorDict:
        """Play one greedy episode per ``trainer.eval_env`` row; one record each (on the CPU).

        Every evaluation plays the same episodes (the eval env's and the tie-breaking random
        streams restart), so evaluation is a function of the tables alone; with one eval seed
        for all learners (as ``run_experiment`` sets up) every learner meets the same episodes.

        Returns a TensorDict ``[P * eval_episodes]`` (learner ``p``'s episodes are rows
        ``p * n .. p * n + n - 1``): ``learner``, ``seed``, ``episode`` (the same index is the
        same start for every learner), ``return``, ``length`` (steps until the episode ended or
        ``eval_max_steps``), ``success``, ``truncated`` (the env's time limit or
        ``eval_max_steps`` ended it), ``start`` (the reset observation) and the root's decisions:
        ``decisions [.., MAX_DECISIONS]`` (the root's children in the order it invoked them,
        node indices, -1 after the last; the first ``MAX_DECISIONS`` only) and ``n_decisions``.

        ``learners`` (indices): play only these learners' episodes (each as in a full
        evaluation: the other rows are split off after the start, as finished rows are); the
        other rows' records stay at 0 length, unfinished. An env or agent that cannot split
        rows (``subset_safe``, ``HierarchicalAgent.subset``) plays them all.
        """
        return _episodes(trainer, learners)[0]

    def limit_note(self) -> str:
        """How many episodes hit the step limit, the first one's cycle (``loops.limit_note``)."""
        if self.last_records is None:
            return ""
        return limit_note(self.last_records, self.last_loops or [])

    def summary(self, learner: int) -> dict:
        """``final_eval_step_limit``: ``learner``'s latest episodes that hit the step limit.

        Each ``{"episode": index, "loop": the cycle it repeated}``.
        """
        records = self.last_records
        if records is None:
            return {}
        hit = (records["truncated"] & (records["learner"] == learner)).nonzero().flatten()
        loops = self.last_loops or [""] * records.batch_size[0]
        return {
            "final_eval_step_limit": [
                {"episode": int(records["episode"][r]), "loop": loops[r]} for r in hit.tolist()
            ]
        }


def _episodes(trainer, learners=None) -> tuple[TensorDict, str | None, Loops | list[str]]:
    """``EpisodicEvaluator.episodes``, the signal that cut them short, and the loops.

    The signal is ``None`` when none did; the loops: per episode the cycle it looped in, if it
    hit the step limit (``loops.loop_texts``).
    """
    env, cfg = trainer.eval_env, trainer.config
    if env is None:
        raise ValueError("no evaluation env: give the Trainer an eval_env (eval_episodes > 0)")
    if env.rng is not None:
        env.rng.load_state_dict({"counter": 0})
    agent = trainer.evaluation_agent(env, "eval-explore")  # its tie-breaking starts afresh
    agent.freeze_values(cfg.eval_max_steps)  # the tables are frozen: values per state once
    start = env.reset()
    action = agent.start(start)
    episodes = EvalEpisodes(env.batch_size, env.device)
    if learners is not None and env.subset_safe:  # only these learners' rows play
        playing = _only(learners, trainer.P, agent, env, action, episodes)
        if playing is None:  # nothing to play
            records = episodes.records(start, trainer.env.seeds, env.envs_per_learner)
            return records, None, episodes.loops
        agent, env, action = playing
    if static_shapes(env.device):  # (a read synchronises: the checks wait for the reads)
        with deferred_meanwhile(env, agent.executor) as checks:
            cut = _play(trainer, agent, env, action, episodes, checks)
    else:
        cut = _play(trainer, agent, env, action, episodes, None)
    records = episodes.records(start, trainer.env.seeds, trainer.eval_env.envs_per_learner)
    return records, cut, episodes.loops


#: off the CPU, greedy episodes read the device (rows still playing, checks) every this many
#: steps (on the CPU every step: a read there costs nothing and finished rows stop sooner)
READ_EVERY = 8


def _play(trainer, agent, env, action, episodes: EvalEpisodes, checks: list | None):
    """Step the greedy episodes to their ends or ``eval_max_steps`` (``episodes.episodes``).

    Returns the signal that ended them early (``signals.stop_requested``; polled every step,
    so a SIGTERM ends a minutes-long evaluation within a step), or ``None``.

    ``checks``: the agent's deferred checks (``deferred_meanwhile``), or ``None`` (immediate
    checks, a read every step: the CPU). With them the device is read every ``READ_EVERY``
    steps (and at the last): how many rows still play (the loop stops at none and steps only
    those once half have finished) and whether a step broke a check (raised with its
    immediate message).
    """
    cfg, graph = trainer.config, trainer.graph
    deferred = checks is not None
    read_every, checks = (READ_EVERY, checks) if deferred else (1, [])
    decisions_on = agent.executor.batch_size == env.batch_size and agent.executor.depth > 1
    finite_only = trainer.executor_config.on_bad_step == "skip"
    bar = progress_bar(cfg.progress, total=env.batch_size, desc="eval", unit="episode", leave=False)
    cut = None
    for t in range(cfg.eval_max_steps):
        cut = stop_requested()
        if cut is not None:
            break
        read = (t + 1) % read_every == 0 or t + 1 == cfg.eval_max_steps
        if decisions_on:
            episodes.record_root_decisions(agent.executor, graph, read)
        td = env.step(action)
        step = entries(td)  # (a plain dict: reading a TensorDict's key costs microseconds)
        episodes.add(step, counted_reward(step, finite_only), cfg.success_key, read)
        if read:
            raise_pending(checks)
            bar.update(bar.total - episodes.alive - bar.n)  # the episodes finished so far
            if episodes.alive == 0:
                break
            if env.subset_safe and episodes.alive <= env.batch_size // 2 and env.batch_size >= 32:
                keep = (~episodes.now["finished"]).nonzero().squeeze(1)
                smaller = agent.subset(keep)  # step only the rows still playing from now on
                if smaller is not None:
                    agent, env, td = smaller, env.subset(keep), td[keep]
                    episodes.compact(keep)
                    checks = defer_reads(env, agent.executor) if deferred else []
        action = agent.step(td)
    bar.close()
    raise_pending(checks)
    if decisions_on:
        episodes.record_root_decisions(agent.executor, graph, True)
    return cut


class EvalHistory:
    """What the evaluations of a run found: the curve, first hits, the latest details.

    Args:
        n_learners: ``P``.
    """

    def __init__(self, n_learners: int) -> None:
        self.curve: list[tuple[int, list[float]]] = []
        self.first_hit: list[int | None] = [None] * n_learners
        self.last_success: list[float] = []
        self.last_steps: list[float] = []

    def record(self, step: int, values, success, steps, real_steps, threshold) -> None:
        """Add one evaluation at ``step``; a learner reaching ``threshold`` is noted once."""
        self.last_success, self.last_steps = success, steps
        self.curve.append((step, values))
        for p, v in enumerate(values):
            if threshold is not None and self.first_hit[p] is None and v >= threshold:
                self.first_hit[p] = int(real_steps[p])

    def state_dict(self) -> dict:
        """The history, in a checkpoint's keys."""
        return {
            "curve": [[s, list(v)] for s, v in self.curve],
            "first_hit": [-1 if h is None else h for h in self.first_hit],
            "last_eval": {"success": list(self.last_success), "steps": list(self.last_steps)},
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``."""
        self.curve[:] = [(int(s), [float(x) for x in v]) for s, v in state["curve"]]
        self.first_hit = [None if h < 0 else int(h) for h in state["first_hit"]]
        last = state.get("last_eval", {})
        self.last_success = [float(x) for x in last.get("success", [])]
        self.last_steps = [float(x) for x in last.get("steps", [])]


class EvalEpisodes:
    """The running results of greedy evaluation episodes, one row each.

    ``now`` holds the rows still stepped (``live``: their indices among all rows); ``compact``
    keeps only some of them, after saving every row's results so far.
    """

    def __init__(self, batch_size: int, device) -> None:
        def zeros(dtype=torch.float32, *shape):
            return torch.zeros(batch_size, *shape, dtype=dtype, device=device)

        self.now = {
            "return": zeros(),
            "length": zeros(),
            "success": zeros(torch.bool),
            "truncated": zeros(torch.bool),
            "finished": zeros(torch.bool),
            "decisions": zeros(torch.long, MAX_DECISIONS) - 1,
            "n_decisions": zeros(torch.long),
        }
        self.all = {k: v.clone() for k, v in self.now.items()}
        self.live = torch.arange(batch_size, device=device)
        self.alive = batch_size  # rows of ``now`` still playing
        self.unread = False  # ``add`` has seen steps since it last counted ``alive``
        self.recent = RecentStates()  # the last observations of each row (``loops``)
        self.t = 0  # steps added
        self.loops: Loops | list[str] = [""] * batch_size

    def _save(self) -> None:
        for k, v in self.now.items():
            self.all[k][self.live] = v

    def add(self, td, reward: torch.Tensor, success_key: str, read: bool = True) -> int:
        """Account one env step of the current rows; how many are still playing.

        ``td``: the step (a TensorDict or its ``entries``). (A step where no episode ends only
        adds to the returns and lengths: success and truncation need an end.) ``read=False``:
        no read of the device; ``alive`` (returned) is then as of the last read.
        """
        now, playing = self.now, ~self.now["finished"]
        self._remember(td, playing)
        now["return"] += reward * playing
        now["length"].add_(playing)
        ended = td["terminated"] | td["truncated"]
        if read and not self.unread and not bool(ended.any()):
            return self.alive
        now["success"] |= succeeded(td, success_key) & playing
        now["truncated"] |= td["truncated"] & ~td["terminated"] & playing
        now["finished"] |= ended
        self.unread = not read  # (rows may have ended since the last count)
        if read:
            self.alive = playing.shape[0] - int(now["finished"].sum())
        return self.alive

    def _remember(self, td, playing: torch.Tensor) -> None:
        """Keep the step's observation of each playing row at slot ``t % LOOP_WINDOW``.

        ``t`` is the step's index: every row's episode starts at the evaluation's start, so a
        row that still plays is at its own step ``t`` (two ops a step, no read of the device).
        """
        codes = self.recent.codes(td)
        if "recent" not in self.now:  # (the fields are known at the first step)
            shape = (self.all["return"].shape[0], LOOP_WINDOW, codes.shape[1])
            self.all["recent"] = codes.new_full(shape, -1)
            self.now["recent"] = self.all["recent"][self.live]
        ring = self.now["recent"].select(1, self.t % LOOP_WINDOW)
        ring.copy_(torch.where(playing[:, None], codes, ring))
        self.t += 1

    def record_root_decisions(self, executor, graph: TaskGraph, read: bool = True) -> None:
        """After ``act``: the root's new child in each row still playing.

        The first ``MAX_DECISIONS`` are kept, in order. (With ``read``, a step where no root
        chooses, e.g. while every row loops inside a subtask, is skipped after one read.)
        """
        now = self.now
        new = executor.invoked[:, 1] & ~now["finished"]
        if read and not bool(new.any()):
            return
        child = torch.take(graph.inst_node, executor.stack.inst[:, 1].clamp_min(0))
        count = now["n_decisions"]
        slot = count.clamp_max(MAX_DECISIONS - 1)[:, None]
        keep = new & (count < MAX_DECISIONS)
        kept = torch.where(keep, child, now["decisions"].gather(1, slot)[:, 0])
        now["decisions"].scatter_(1, slot, kept[:, None])
        count.add_(new)

    def compact(self, keep: torch.Tensor) -> None:
        """Step only ``keep`` (indices into the current rows) from now on."""
        self._save()
        self.now = {k: v[keep] for k, v in self.now.items()}
        self.live = self.live[keep]
        self.alive = int((~self.now["finished"]).sum())

    def records(self, start: TensorDict, seeds, n: int) -> TensorDict:
        """Every row's record (see ``Trainer.evaluate_episodes``); ``n`` episodes per seed."""
        self._save()
        out = {k: v.cpu() for k, v in self.all.items()}
        row = torch.arange(out["return"].shape[0])
        truncated = out["truncated"] | ~out["finished"]
        if "recent" in out:  # (the texts are made when asked for: no reads here)
            self.loops = Loops(out["recent"], out["length"], truncated, self.recent.names)
        fields = {
            "learner": row // n,
            "seed": torch.tensor(seeds).repeat_interleave(n),
            "episode": row % n,
            **{k: out[k] for k in ("return", "length", "success", "decisions", "n_decisions")},
            "truncated": truncated,
            "start": start.exclude(*_STEP_FIELDS).cpu(),
        }
        return TensorDict(fields, batch_size=[row.shape[0]])


def _only(learners, n_learners: int, agent, env, action, episodes: EvalEpisodes):
    """``(agent, env, action)`` of the rows of ``learners`` only; ``None``: they hold no row.

    ``episodes`` is compacted to those rows; all stay if the agent cannot split rows.
    """
    keep = _learner_mask(learners, n_learners).to(env.device)
    keep = keep.repeat_interleave(env.envs_per_learner).nonzero().squeeze(1)
    if keep.numel() == 0:
        return None
    smaller = agent.subset(keep)
    if smaller is None:
        return agent, env, action
    episodes.compact(keep)
    return smaller, env.subset(keep), action.index_select(0, keep)


def _learner_mask(learners, n_learners: int) -> torch.Tensor:
    """``[P]``: True at ``learners`` (indices in ``[0, P)``); a ``ValueError`` otherwise."""
    index = torch.as_tensor(learners, dtype=torch.long).reshape(-1)
    if index.numel() and not (0 <= int(index.min()) and int(index.max()) < n_learners):
        raise ValueError(f"learners must be indices in [0, {n_learners}), got {learners}")
    return torch.zeros(n_learners, dtype=torch.bool).index_fill_(0, index, True)


def eval_line(step: int, tag: str, values: list[float], seconds: float) -> str:
    """One line for an evaluation's result: the mean over seeds, their range, its cost."""
    name = tag.split("/")[-1].replace("eval_", "greedy ").replace("_", " ")
    finite = [v for v in values if math.isfinite(v)]
    head = f"eval at step {step:,}: {name}"
    if not finite:  # say why, instead of a bare nan
        return (
            f"{head} nan for every seed: no evaluation episode ended, or the evaluation window "
            f"saw no time (raise eval_max_steps or the window) [{seconds:.1f} s]"
        )
    mean = sum(finite) / len(finite)
    seeds = f"{len(finite)} seeds {min(finite):.4g} .. {max(finite):.4g}"
    missing = f", {len(values) - len(finite)} nan" if len(finite) < len(values) else ""
    return f"{head} {mean:.4g} ({seeds}{missing}) [{seconds:.1f} s]"


def counted_reward(td, finite_only: bool) -> torch.Tensor:
    """The step's reward as returns count it (``td``: the step, or its ``entries``).

    With ``finite_only`` (``ExecutorConfig.on_bad_step="skip"``) a skipped bad step counts 0.
    """
    reward = td["reward"]
    return torch.where(reward.isfinite(), reward, 0.0) if finite_only else reward


def succeeded(td, key: str) -> torch.Tensor:
    """``[B]``: the episode terminated successfully (``key``: see ``TrainConfig.success_key``).

    ``td``: the step (a TensorDict or its ``entries``).
    """
    if key == "terminated":
        return td["terminated"]
    flag = ~td[key[1:]] if key.startswith("!") else td[key]
    return flag & td["terminated"]
