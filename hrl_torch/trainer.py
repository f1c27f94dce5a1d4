"""The training loop: batched env -> executor -> learner, with evaluation, logging and resume.

One ``Trainer`` trains a population of ``P`` learners (one per seed) on ``P * E`` env rows. Step
counts are *env steps per learner* (the ``E`` rows of a learner each add one per batched step);
exploration and step-size schedules read that count.
"""

from __future__ import annotations

import copy
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import torch
from tensordict import TensorDict
from tqdm import tqdm

from hrl_torch.agent import HierarchicalAgent
from hrl_torch.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from hrl_torch.executor import ExecutorConfig
from hrl_torch.exploration import Exploration, Greedy
from hrl_torch.graph import TaskGraph
from hrl_torch.learners.base import Learner
from hrl_torch.monitor import LeafRewardMonitor
from hrl_torch.multiagent import MultiAgentAgent, MultiAgentConfig, agent_rng
from hrl_torch.ops import entries
from hrl_torch.rng import BatchRNG
from hrl_torch.runlog import RunLogger


def warn_cpu_threads(device) -> None:
    """Warn when torch runs this CPU hot path on more than one thread.

    A step is many small ops. On an idle machine two threads were no slower, but with another
    process on a core a taxi step at 10 x 512 was 9-75x slower (docs/design.md#threads). The
    CLI sets one thread itself.
    """
    if torch.device(device).type == "cpu" and torch.get_num_threads() > 1:
        warnings.warn(
            f"torch uses {torch.get_num_threads()} threads: the batched hot path (many small "
            "ops) slows down many times over when another process shares a core; call "
            "torch.set_num_threads(1) before training",
            stacklevel=_first_caller_outside_package(),
        )


def _first_caller_outside_package() -> int:
    """``stacklevel`` for a warning raised by our caller: the first frame outside hrl_torch."""
    package = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frame, level = sys._getframe(1), 1  # level 1: the function that calls warnings.warn
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level


@dataclass
class TrainConfig:
    """Training options.

    Attributes:
        steps: env steps per learner to train for.
        eval_every: env steps per learner between greedy evaluations (0: only at the end).
        eval_episodes: greedy evaluation episodes per learner.
        eval_max_steps: cap on the length of an evaluation episode.
        log_every: env steps per learner between training-metric logs.
        threshold: record the first evaluation at which a learner's return reaches this.
        checkpoint_every: env steps per learner between checkpoints (0: only at the end).
        progress: show a progress bar.
        success_key: observation field that marks a successful episode end (``terminated``
            by default; e.g. ``success`` where some terminations are failures; ``"!name"``:
            the termination is a success where the field ``name`` is False).
        check_leaf_rewards: warn when one abstract state of a primitive sees different rewards
            (``hrl_torch.monitor.LeafRewardMonitor``; single-agent training only).
    """

    steps: int = 50_000
    eval_every: int = 5_000
    eval_episodes: int = 100
    eval_max_steps: int = 1_000
    log_every: int = 2_000
    threshold: float | None = None
    checkpoint_every: int = 0
    progress: bool = True
    success_key: str = "terminated"
    check_leaf_rewards: bool = False


@dataclass
class TrainResult:
    """Per-learner outcome of ``Trainer.train``.

    Step counts: ``env_steps_per_learner`` (and the curve's x axis, budgets and schedules) is the
    batched clock, ``E`` per batched step; ``env_steps`` and ``steps_to_threshold`` count the
    env steps each learner really took (a row being auto-reset after an episode takes none).
    """

    final_eval: list[float]
    final_success: list[float]
    steps_to_threshold: list[int | None]
    env_steps_per_learner: int  # the schedule clock: batched steps x E

    train_seconds: float
    env_steps_per_second: float
    curve: list[tuple[int, list[float]]] = field(default_factory=list)
    final_steps: list[float] = field(default_factory=list)
    env_steps: list[int] = field(default_factory=list)  # real env steps per learner
    interrupted: str | None = None  # "SIGINT" / "SIGTERM": stopped early, checkpoint written


class Trainer:
    """Trains ``learner`` on ``env`` through ``graph``'s Task-Stack executor.

    Args:
        env: batched training env with ``P * E`` rows.
        graph: the task graph.
        learner: the population learner (``P`` = ``env.n_learners``).
        exploration: exploration strategy during training.
        config: loop options.
        eval_env: batched env with ``P * eval_episodes`` rows for greedy evaluation.
        executor_config: guard and all-states options.
        logger: where metrics go (``None``: nowhere).
        evaluator: replaces the episodic evaluation, e.g. a
            ``hrl_torch.continuing.ThroughputEvaluator`` for continuing tasks; it also sees
            every training step (``observe``) and adds its metrics at each log (``flush``).
        collector: step the env through a TorchRL ``Collector`` and learn from its frames
            (``hrl_torch.collector``); the same tables as the direct loop.
        multiagent: how the agents of a multi-agent env cooperate (``hrl_torch.multiagent``).
    """

    def __init__(
        self,
        env,
        graph: TaskGraph,
        learner: Learner,
        exploration: Exploration,
        config: TrainConfig | None = None,
        eval_env=None,
        executor_config: ExecutorConfig | None = None,
        logger: RunLogger | None = None,
        evaluator=None,
        collector: bool = False,
        multiagent: MultiAgentConfig | None = None,
    ) -> None:
        self.env, self.graph, self.learner = env, graph, learner
        warn_cpu_threads(env.device)
        self.collector = collector
        self._source = None  # the collector path's frames (created at the first step)
        self._steps = None
        self._resume_obs = None
        self.evaluator = evaluator
        self.config = config or TrainConfig()
        self.executor_config = executor_config or ExecutorConfig()
        self.eval_env = eval_env
        self.logger = logger
        self.multiagent = multiagent
        self.n_agents = getattr(env, "n_agents", None)  # a multi-agent env (Chapter 6)
        self._check_table_sets(learner, env.n_learners, self.n_agents, multiagent)
        self.P, self.E = env.n_learners, env.envs_per_learner
        self.exploration = exploration
        self.agent = self.make_agent(env, "explore")
        self.rows = env.learner_of_row()
        self.action: torch.Tensor | None = None
        self.train_seconds = 0.0
        self._episodes = _EpisodeTracker(
            env.batch_size,
            self.P,
            self.E,
            self.config.success_key,
            env.device,
            finite_only=self.executor_config.on_bad_step == "skip",
        )
        self.curve: list[tuple[int, list[float]]] = []
        self.first_hit: list[int | None] = [None] * self.P
        # env steps each learner really took (rows being auto-reset take none)
        self.real_steps = torch.zeros(self.P, dtype=torch.float64, device=env.device)
        self.leaf_monitor = None
        if self.config.check_leaf_rewards:
            if self.n_agents is not None:
                raise ValueError("check_leaf_rewards is for single-agent training")
            self.leaf_monitor = LeafRewardMonitor(graph, self.P, device=env.device)
        self._next = {"log": 0, "eval": self.config.eval_every, "ckpt": 0}
        #: what a checkpoint records of the run (``hrl_torch.experiment.run_config``)
        self.run_config: dict | None = None
        self._last_success: list[float] = []  # the latest evaluation's details
        self.last_eval_records: TensorDict | None = None  # its episodes (evaluate_episodes)
        self._last_steps: list[float] = []

    @staticmethod
    def _check_table_sets(learner: Learner, n_learners: int, n_agents, multiagent) -> None:
        """A ``ValueError`` unless the learner has a table set per learner (and agent)."""
        sets = n_learners
        if n_agents is not None:
            sets = (multiagent or MultiAgentConfig()).table_sets(n_learners, n_agents)
        if learner.n_learners != sets:
            raise ValueError(f"learner has {learner.n_learners} table sets, the env needs {sets}")

    # ------------------------------------------------------------------ stepping
    @property
    def step(self) -> int:
        """Env steps per learner so far (the clock of the schedules)."""
        return self.agent.clock

    @step.setter
    def step(self, value: int) -> None:
        self.agent.clock = value

    @property
    def executor(self):
        """The training rows' Task-Stack executor."""
        return self.agent.executor

    @property
    def policy(self):
        """The training policy."""
        return self.agent.policy

    def train_step(self) -> None:
        """One batched step: every row takes one primitive action, the learner updates."""
        td, batch = self._collected_step() if self.collector else self._direct_step()
        if self.agent.learn:
            self.agent.update(batch)
        if self.leaf_monitor is not None and batch is not None:
            self.leaf_monitor.observe(batch, self.rows)
        real = self._episodes.add(td)
        self.real_steps.index_add_(0, self.rows, real.double())
        if self.evaluator is not None:  # continuing tasks: training throughput
            self.evaluator.observe(td, self.rows, self.P)

    def _direct_step(self):
        """``env.step`` and ``agent.decide``: the step's output and its transitions."""
        if self.action is None:
            self.action = self.agent.start(self.env.reset())
        td = self.env.step(self.action)
        self.action, batch = self.agent.decide(td)
        return td, batch

    def _collected_step(self):
        """The next frame of the TorchRL collector: the step's output and its transitions."""
        if self._steps is None:
            from hrl_torch.collector import CollectorSource  # TorchRL only on this path

            self._source = CollectorSource(self.env, self.agent, self._resume_obs)
            self._steps = self._source.steps()
            self._resume_obs = None
        return next(self._steps)

    def close(self) -> None:
        """Stop the collector of the collector path (if one runs)."""
        if self._source is not None:
            self._source.shutdown()
            self._source = self._steps = None

    def train(self, steps: int | None = None, run_dir=None) -> TrainResult:
        """Train until ``steps`` env steps per learner (default ``config.steps``).

        SIGINT (Ctrl-C) or SIGTERM ends the run after the current step: a checkpoint is written
        (with ``run_dir``) and the result says ``interrupted``; a second signal acts as usual.
        """
        cfg = self.config
        total = cfg.steps if steps is None else steps
        bar = tqdm(
            total=total,
            initial=self.step,
            unit="step",
            disable=not cfg.progress,
            desc="train",
            dynamic_ncols=True,
        )
        with _StopOnSignal() as stop:
            while self.step < total and stop.signal is None:
                t0 = time.perf_counter()
                self.train_step()
                self.train_seconds += time.perf_counter() - t0
                bar.update(self.E)
                self._after_step(cfg, run_dir)
        bar.close()
        self._warn_leaf_rewards()
        final, success = [float("nan")] * self.P, [float("nan")] * self.P
        steps = [float("nan")] * self.P
        if self.eval_env is not None and stop.signal is None:
            if not self.curve or self.curve[-1][0] != self.step:
                self._evaluate_and_log()
        if self.curve and self._last_success:  # the latest evaluation
            final, success, steps = self.curve[-1][1], self._last_success, self._last_steps
        if run_dir is not None:
            self.save(f"{run_dir}/checkpoint.pt")
        sps = float(self.real_steps.sum()) / max(self.train_seconds, 1e-9)
        return TrainResult(
            final,
            success,
            list(self.first_hit),
            self.step,
            self.train_seconds,
            sps,
            list(self.curve),
            steps,
            [int(x) for x in self.real_steps],
            stop.signal,
        )

    def _after_step(self, cfg: TrainConfig, run_dir) -> None:
        """Log, evaluate and checkpoint when their intervals are due."""
        if self.step >= self._next["log"]:
            self._log_training()
            self._next["log"] = self.step + cfg.log_every
        if self.eval_env is not None and cfg.eval_every and self.step >= self._next["eval"]:
            self._evaluate_and_log()
            self._next["eval"] = self.step + cfg.eval_every
        if run_dir is not None and cfg.checkpoint_every and self.step >= self._next["ckpt"]:
            self.save(f"{run_dir}/checkpoint.pt")
            self._next["ckpt"] = self.step + cfg.checkpoint_every

    # ------------------------------------------------------------------ evaluation
    def evaluate(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Greedy episodes on ``eval_env``: mean return and success rate per learner ``[P]``.

        (The mean episode length per learner is kept in ``last_eval_steps``, every episode in
        ``last_eval_records``: see ``evaluate_episodes``.)
        """
        if self.evaluator is not None:  # continuing tasks: greedy throughput, no episodes
            self.last_eval_steps = torch.full((self.P,), float("nan"))
            self.last_eval_records = None
            return self.evaluator.evaluate(self)
        records = self.evaluate_episodes()
        self.last_eval_records = records
        n = self.eval_env.envs_per_learner
        self.last_eval_steps = records["length"].view(-1, n).mean(1)
        success = records["success"].float().view(-1, n).mean(1)
        return records["return"].view(-1, n).mean(1), success

    def evaluate_episodes(self) -> TensorDict:
        """Play one greedy episode per ``eval_env`` row; one record per episode (on the CPU).

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
        """
        env, cfg = self.eval_env, self.config
        if hasattr(env, "rng"):
            env.rng.load_state_dict({"counter": 0})
        agent = self.evaluation_agent(env, "eval-explore")  # its tie-breaking starts afresh
        agent.freeze_values(cfg.eval_max_steps)  # the tables are frozen: values per state once
        start = env.reset()
        action = agent.start(start)
        episodes = _EvalEpisodes(env.batch_size, env.device)
        decisions_on = agent.executor.batch_size == env.batch_size and agent.executor.depth > 1
        finite_only = self.executor_config.on_bad_step == "skip"
        compactable = getattr(env, "subset_safe", False)
        for _ in range(cfg.eval_max_steps):
            if decisions_on:
                episodes.record_root_decisions(agent.executor, self.graph)
            td = env.step(action)
            alive = episodes.add(td, _counted_reward(td, finite_only), cfg.success_key)
            if alive == 0:
                break
            if compactable and alive <= env.batch_size // 2 and env.batch_size >= 32:
                keep = (~episodes.now["finished"]).nonzero().squeeze(1)
                smaller = agent.subset(keep)  # step only the rows still playing from now on
                if smaller is not None:
                    agent, env, td = smaller, env.subset(keep), td[keep]
                    episodes.compact(keep)
            action = agent.step(td)
        if decisions_on:
            episodes.record_root_decisions(agent.executor, self.graph)
        return episodes.records(start, self.env.seeds, self.eval_env.envs_per_learner)

    def make_agent(self, env, stream: str, exploration=None, **options) -> HierarchicalAgent:
        """An agent over ``env``'s rows (a ``MultiAgentAgent`` for a multi-agent env).

        Its random numbers are the stream ``stream`` of the env's seeds.
        """
        exploration = self.exploration if exploration is None else exploration
        e = env.envs_per_learner
        uses = getattr(self.learner, "uses", None)
        if self.config.check_leaf_rewards and uses is not None:
            options.setdefault("uses", uses | {"primitive"})  # the monitor reads the steps
        if self.n_agents is None:
            rng = BatchRNG(env.seeds, e, stream)
            args = (self.graph, self.learner, exploration, rng, e, self.executor_config)
            return HierarchicalAgent(*args, **options)
        rng = agent_rng(env.seeds, e, self.n_agents, stream).to(env.device)
        config = self.multiagent or MultiAgentConfig()
        return MultiAgentAgent(
            self.graph,
            self.learner,
            exploration,
            rng,
            e,
            self.n_agents,
            self.executor_config,
            cooperation=config.cooperation,
            scheme=config.scheme,
            shared_tables=config.shared_tables,
            communication=config.communication,
            **options,
        )

    def evaluation_agent(self, env, rng_stream: str, transitions: bool = False):
        """A greedy, non-learning agent over ``env``'s rows at the current step (evaluation).

        Its random numbers (ties) restart from the stream ``rng_stream`` of the env's seeds.
        """
        agent = self.make_agent(
            env, rng_stream, Greedy(), learn=False, evaluate=True, transitions=transitions
        )
        agent.clock = self.step
        return agent

    def _evaluate_and_log(self) -> None:
        start = time.perf_counter()
        mean, success = self.evaluate()
        self.eval_seconds = time.perf_counter() - start  # the cost of one evaluation
        if self.logger and self.last_eval_records is not None:
            self.logger.log_episodes(self.step, self.last_eval_records, self.graph.names)
        values = mean.tolist()
        self._last_success = success.tolist()
        self._last_steps = self.last_eval_steps.tolist()
        self.curve.append((self.step, values))
        threshold = self.config.threshold
        for p, v in enumerate(values):
            if threshold is not None and self.first_hit[p] is None and v >= threshold:
                self.first_hit[p] = int(self.real_steps[p])
        if self.logger:
            tags = getattr(self.evaluator, "tags", ("charts/eval_return", "charts/eval_success"))
            scalars = {tags[0]: values, tags[1]: self._last_success}
            scalars.update(getattr(self.evaluator, "last_eval", {}))  # e.g. its ratio
            scalars["perf/eval_seconds"] = [self.eval_seconds] * self.P
            self.logger.log(self.step, scalars)

    def _per_seed(self, counts: torch.Tensor) -> torch.Tensor:
        """Counters per table set ``[sets, ...]`` summed per seed ``[P, ...]``.

        A multi-agent learner has a table set per seed and agent.
        """
        return counts.view(self.P, -1, *counts.shape[1:]).sum(1)

    def _warn_leaf_rewards(self) -> None:
        """Warn about primitives whose abstract states merge different rewards (if checked)."""
        if self.leaf_monitor is not None:
            for line in self.leaf_monitor.new_violations():
                warnings.warn(line, stacklevel=3)

    def _log_training(self) -> None:
        self._warn_leaf_rewards()
        extra = self.evaluator.flush() if self.evaluator is not None else {}
        if not self.logger:
            return
        g = self.graph
        scalars = self._episodes.flush()
        scalars.update(extra)
        scalars["perf/env_steps_per_s"] = [
            self.step * self.P / max(self.train_seconds, 1e-9)
        ] * self.P
        stats = self.executor.stats
        calls, ends = self._per_seed(stats.calls), self._per_seed(stats.ends)
        durations, successes = self._per_seed(stats.durations), self._per_seed(stats.successes)
        td_abs, td_count = (
            self._per_seed(self.learner.td_abs),
            self._per_seed(self.learner.td_count),
        )
        for k in g.subtasks():
            name = g.names[k]
            scalars[f"hrl/{name}/calls"] = calls[:, k].tolist()
            scalars[f"hrl/{name}/mean_duration"] = _ratio(durations[:, k], ends[:, k])
            scalars[f"hrl/{name}/success"] = _ratio(successes[:, k], ends[:, k])
            scalars[f"losses/{name}/td_error"] = _ratio(td_abs[:, k], td_count[:, k])
        if self.executor_config.on_bad_step == "skip":  # bad env steps skipped so far
            scalars["charts/skipped_steps"] = self._per_seed(self.executor.skipped_steps).tolist()
        com = self.multiagent.communication if self.multiagent else None
        if com is not None:  # COM-Cooperative HRL: the share of U_l choices made communicating
            asked = calls[:, g.index[com.com]]
            scalars["charts/communication_rate"] = _ratio(
                asked, asked + calls[:, g.index[com.not_com]]
            )
        stats.reset()
        self.learner.td_abs.zero_()
        self.learner.td_count.zero_()
        self.logger.log(self.step, scalars)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """Everything needed to continue this run exactly."""
        state = {
            "step": self.step,
            "train_seconds": self.train_seconds,
            "learner": self.learner.state_dict(),
            "env": self.env.state_dict(),
            "executor": self.executor.state_dict(),
            "explore_rng": self.policy.rng.state_dict(),
            "action": self.action if self.action is not None else torch.zeros(0),
            "collector": self._pending_obs(),
            "episodes": self._episodes.state_dict(),
            "curve": [[s, list(v)] for s, v in self.curve],
            "first_hit": [-1 if h is None else h for h in self.first_hit],
            "real_steps": self.real_steps.clone(),
            "next": dict(self._next),
            "last_eval": {
                "success": list(self._last_success),
                "steps": list(self._last_steps),
            },
        }
        if self.eval_env is not None:
            state["eval_env"] = self.eval_env.state_dict()
        if hasattr(self.evaluator, "state_dict"):
            state["evaluator"] = self.evaluator.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``; on any mismatch nothing changes and ``CheckpointError`` rises."""
        backup = copy.deepcopy(self.state_dict())
        try:
            self._apply(state)
        except Exception as err:
            self._apply(backup)
            raise CheckpointError(f"checkpoint does not fit this run: {err}") from err

    def _apply(self, state: dict) -> None:
        self.learner.load_state_dict(state["learner"])
        self.env.load_state_dict(state["env"])
        self.executor.load_state_dict(state["executor"])
        self.policy.rng.load_state_dict(state["explore_rng"])
        self._episodes.load_state_dict(state["episodes"])
        if hasattr(self.evaluator, "load_state_dict"):
            self.evaluator.load_state_dict(state.get("evaluator", {}))
        if self.eval_env is not None and "eval_env" in state:
            self.eval_env.load_state_dict(state["eval_env"])
        action = state["action"]
        self.action = None if action.numel() == 0 else action.clone()
        pending = state.get("collector") or {}
        if self.collector != bool(pending) and int(state["step"]) > 0:
            raise ValueError(
                "a checkpoint of the direct loop cannot continue on the collector path, "
                "nor the other way round"
            )
        self.close()
        b = [self.env.batch_size]
        self._resume_obs = TensorDict(pending, batch_size=b) if pending else None
        if not state["env"]:  # an env that cannot be checkpointed (gymnasium): new episodes
            self.action = None
        self.step = int(state["step"])
        self.train_seconds = float(state["train_seconds"])
        self.curve = [(int(s), [float(x) for x in v]) for s, v in state["curve"]]
        self.first_hit = [None if h < 0 else int(h) for h in state["first_hit"]]
        self.real_steps = state["real_steps"].clone()
        self._next = {k: int(v) for k, v in state["next"].items()}
        last = state.get("last_eval", {})
        self._last_success = [float(x) for x in last.get("success", [])]
        self._last_steps = [float(x) for x in last.get("steps", [])]

    def _pending_obs(self) -> dict:
        """Collector path: the domain output the agent acts on next (empty: direct loop)."""
        if not self.collector:
            return {}
        if self._source is not None:
            return self._source.pending.to_dict()
        return {} if self._resume_obs is None else self._resume_obs.to_dict()

    def save(self, path) -> None:
        """Write a checkpoint of this trainer (and of the run's configuration, if known)."""
        state = {"trainer": self.state_dict()}
        if self.run_config is not None:
            state["run"] = self.run_config
        save_checkpoint(path, state)

    def load(self, path) -> None:
        """Continue from a checkpoint written by ``save``."""
        self.load_state_dict(load_checkpoint(path)["trainer"])


class _StopOnSignal:
    """Within ``with``: the first SIGINT or SIGTERM is recorded, not raised.

    ``signal`` holds its name; the previous handlers come back at once, so a second signal
    acts as usual. Outside the main thread (where handlers cannot be set) nothing changes.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signal: str | None = None
        self._previous: dict = {}

    def __enter__(self) -> _StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            self._previous = {s: signal.signal(s, self._record) for s in self.SIGNALS}
        return self

    def _record(self, signum, frame) -> None:
        self.signal = signal.Signals(signum).name
        self._restore()

    def _restore(self) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous = {}

    def __exit__(self, *exc) -> None:
        self._restore()


_STEP_FIELDS = ("reward", "duration", "terminated", "truncated", "is_init")
#: root decisions kept per evaluation episode
MAX_DECISIONS = 32


class _EvalEpisodes:
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

    def _save(self) -> None:
        for k, v in self.now.items():
            self.all[k][self.live] = v

    def add(self, td: TensorDict, reward: torch.Tensor, success_key: str) -> int:
        """Account one env step of the current rows; how many are still playing."""
        now, playing = self.now, ~self.now["finished"]
        now["return"] += reward * playing
        now["length"] += playing.float()
        now["success"] |= _succeeded(td, success_key) & playing
        now["truncated"] |= td["truncated"] & ~td["terminated"] & playing
        now["finished"] |= td["terminated"] | td["truncated"]
        return int((~now["finished"]).sum())

    def record_root_decisions(self, executor, graph: TaskGraph) -> None:
        """After ``act``: the root's new child in each row still playing.

        The first ``MAX_DECISIONS`` are kept, in order.
        """
        now = self.now
        new = executor.invoked[:, 1] & ~now["finished"]
        child = graph.inst_node[executor.stack.inst[:, 1].clamp_min(0)]
        count = now["n_decisions"]
        slot = count.clamp_max(MAX_DECISIONS - 1)[:, None]
        keep = new & (count < MAX_DECISIONS)
        kept = torch.where(keep, child, now["decisions"].gather(1, slot)[:, 0])
        now["decisions"].scatter_(1, slot, kept[:, None])
        count += new.long()

    def compact(self, keep: torch.Tensor) -> None:
        """Step only ``keep`` (indices into the current rows) from now on."""
        self._save()
        self.now = {k: v[keep] for k, v in self.now.items()}
        self.live = self.live[keep]

    def records(self, start: TensorDict, seeds, n: int) -> TensorDict:
        """Every row's record (see ``Trainer.evaluate_episodes``); ``n`` episodes per seed."""
        self._save()
        out = {k: v.cpu() for k, v in self.all.items()}
        row = torch.arange(out["return"].shape[0])
        fields = {
            "learner": row // n,
            "seed": torch.tensor(seeds).repeat_interleave(n),
            "episode": row % n,
            **{k: out[k] for k in ("return", "length", "success", "decisions", "n_decisions")},
            "truncated": out["truncated"] | ~out["finished"],
            "start": start.exclude(*_STEP_FIELDS).cpu(),
        }
        return TensorDict(fields, batch_size=[row.shape[0]])


def _counted_reward(td, finite_only: bool) -> torch.Tensor:
    """The step's reward as returns count it (``td``: the step, or its ``entries``).

    With ``finite_only`` (``ExecutorConfig.on_bad_step="skip"``) a skipped bad step counts 0.
    """
    reward = td["reward"]
    return torch.where(reward.isfinite(), reward, 0.0) if finite_only else reward


def _succeeded(td, key: str) -> torch.Tensor:
    """``[B]``: the episode terminated successfully (``key``: see ``TrainConfig.success_key``).

    ``td``: the step (a TensorDict or its ``entries``).
    """
    if key == "terminated":
        return td["terminated"]
    flag = ~td[key[1:]] if key.startswith("!") else td[key]
    return flag & td["terminated"]


def _ratio(num: torch.Tensor, den: torch.Tensor) -> list[float]:
    return torch.where(den > 0, num / den.clamp_min(1), torch.nan).tolist()


class _EpisodeTracker:
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
        self.ret += _counted_reward(f, self.finite_only) * real
        self.length += real
        ended = ((f["terminated"] | f["truncated"]) & real).float()
        won = _succeeded(f, self.success_key)
        values = torch.stack([ended, self.ret, self.length, won.float()])
        self.sums.index_add_(1, self.rows, values * ended)
        keep = 1 - ended
        self.ret *= keep
        self.length *= keep
        return real

    def flush(self) -> dict[str, list[float]]:
        sums = self.sums.cpu()
        n = sums[0]
        out = {
            "charts/episode_return": _ratio(sums[1], n),
            "charts/episode_length": _ratio(sums[2], n),
            "charts/episode_success": _ratio(sums[3], n),
        }
        self.sums.zero_()
        return out

    def state_dict(self) -> dict:
        return {"ret": self.ret.clone(), "length": self.length.clone(), "sums": self.sums.clone()}

    def load_state_dict(self, state: dict) -> None:
        for k in ("ret", "length", "sums"):
            if state[k].shape != getattr(self, k).shape:
                raise ValueError(f"episode tracker {k!r} shape mismatch")
            setattr(self, k, state[k].to(self.rows.device).clone())


def hparams_of(**parts) -> dict:
    """Flatten dataclasses and plain values into one hyperparameter dict for logging."""
    out = {}
    for name, value in parts.items():
        if hasattr(value, "__dataclass_fields__"):
            out.update({f"{name}.{k}": v for k, v in asdict(value).items()})
        elif isinstance(value, Callable):
            out[name] = getattr(value, "__name__", repr(value))
        else:
            out[name] = value
    return out
