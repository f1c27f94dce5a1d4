"""The training loop: batched env -> agent -> learner, with evaluation, logging and checkpoints.

One ``Trainer`` trains a population of ``P`` learners (one per seed) on ``P * E`` env rows. Step
counts are *env steps per learner* (the ``E`` rows of a learner each add one per batched step);
exploration and step-size schedules read that count.

The loop calls the collaborators it is given: an agent factory (``agent``), an evaluator
(``evaluation``), a run log (``runlog``) and the training metrics (``metrics``); it keeps its
state with a ``common.checkpoint.Checkpointer`` and stops cleanly on a signal (``common.signals``).
"""

from __future__ import annotations

import time

import torch
from tensordict import TensorDict
from tqdm import tqdm

from hrl_torch.analysis.monitor import LeafRewardMonitor
from hrl_torch.common import compat
from hrl_torch.common.checkpoint import Checkpointer
from hrl_torch.common.progress import progress_bar
from hrl_torch.common.signals import StopOnSignal
from hrl_torch.common.threads import warn_cpu_threads
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.learners.action_range import use_action_bounds
from hrl_torch.learners.base import Learner
from hrl_torch.learners.init_check import warn_discount_trap
from hrl_torch.modules.exploration import Exploration, Greedy
from hrl_torch.training import metrics
from hrl_torch.training.agent import AgentFactory, HierarchicalAgent, checked_factory
from hrl_torch.training.config import TrainConfig, TrainResult
from hrl_torch.training.counters import LoopCounters
from hrl_torch.training.cuda_graph import step_for
from hrl_torch.training.deferred import defer_checks, raise_pending
from hrl_torch.training.evaluation import EpisodicEvaluator, EvalHistory, Evaluator, eval_line
from hrl_torch.training.metrics import EpisodeTracker
from hrl_torch.training.runlog import RunLogger, hparams_of
from hrl_torch.training.steps import CollectedSteps, DirectSteps

__all__ = ["TrainConfig", "TrainResult", "Trainer", "hparams_of", "warn_cpu_threads"]


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
        evaluator: the greedy evaluation (``evaluation.Evaluator``; default the episodic one),
            e.g. a ``continuing.ThroughputEvaluator`` for continuing tasks; it also sees every
            training step (``observe``) and adds its metrics at each log (``flush``).
        collector: step the env through a TorchRL ``Collector`` and learn from its frames
            (``training.collector``); the same tables as the direct loop.
        agent_factory: builds the agents (``agent.AgentFactory``; default one agent per row; a
            multi-agent env needs ``hrl_torch.multiagent.factory.MultiAgentFactory``).
        multiagent: 0.1's way to say ``agent_factory=MultiAgentFactory(n_agents, multiagent)``
            (deprecated; goes in 0.3.0).
    """

    graph_backend: str | None = None  #: ``"trace"``: ``StepGraph``'s trace backend (any device)

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
        evaluator: Evaluator | None = None,
        collector: bool = False,
        agent_factory: AgentFactory | None = None,
        multiagent=None,
    ) -> None:
        agent_factory = compat.trainer_agent_factory(agent_factory, multiagent, env)
        self.env, self.graph, self.learner, self.exploration = env, graph, learner, exploration
        warn_cpu_threads(env.device)
        warn_discount_trap(learner, stacklevel=3)  # (before any step: the initial values)
        use_action_bounds(learner, env)  # (Gaussian heads without a range take the env's)
        self.collector = collector
        self.evaluator = EpisodicEvaluator() if evaluator is None else evaluator
        self.config = config or TrainConfig()
        self.executor_config = executor_config or ExecutorConfig()
        self.eval_env, self.logger = eval_env, logger
        check_eval_env(env, eval_env)
        self.agents = checked_factory(agent_factory, env, learner, graph)
        self.P, self.E = env.n_learners, env.envs_per_learner
        self.agent = self.make_agent(env, "explore")
        self.rows = env.learner_of_row()
        self.source = (CollectedSteps if collector else DirectSteps)(env.batch_size, self.agent)
        self.deferred = defer_checks(env, self.agent.executor, self.learner)  # (docs/bad-input.md)
        skip, success = self.executor_config.on_bad_step == "skip", self.config.success_key
        self.episodes = EpisodeTracker(env.batch_size, self.P, self.E, success, env.device, skip)
        self.history = EvalHistory(self.P)
        self.curve = self.history.curve  # ``(step, per-learner value)`` of every evaluation
        self.counters = LoopCounters(self.agent, self.P, self.config.eval_every, env.device)
        self.leaf_monitor = None
        if self.config.check_leaf_rewards:
            if self.agents.n_agents is not None:
                raise ValueError("check_leaf_rewards is for single-agent training")
            self.leaf_monitor = LeafRewardMonitor(graph, self.P, device=env.device)
        #: what a checkpoint records of the run (``hrl_torch.runs.experiment.run_config``)
        self.run_config: dict | None = None
        self.last_eval_records: TensorDict | None = None  # the latest evaluation's episodes
        self.partial_eval: dict | None = None  # an evaluation a signal cut short (step, values)
        self.checkpointer = Checkpointer(
            lambda: {
                "learner": self.learner,
                "env": self.env,
                "executor": self.executor,
                "explore_rng": self.policy.rng,
                "episodes": self.episodes,
                "evaluator": self.evaluator,
                "eval_env": self.eval_env,
            },
            flat=(self.source, self.counters, self.history),
            optional=frozenset({"evaluator", "eval_env"}),
        )

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
        """One batched step of every row and the learner (CUDA: a graph, ``cuda_graph``)."""
        replay = self.__dict__.get("_graph") or self.__dict__.setdefault("_graph", step_for(self))
        if replay():  # (it ran the step; inside, it calls this again for the eager step)
            return
        td, batch = self.source.step(self.env)
        if self.agent.learn:
            self.agent.update(batch)
        if self.leaf_monitor is not None and batch is not None:
            self.leaf_monitor.observe(batch, self.rows)
        real = self.episodes.add(td)
        self.counters.real_steps.index_add_(0, self.rows, real.double())
        self.evaluator.observe(td, self.rows, self.P)  # e.g. training throughput

    def close(self) -> None:
        """Stop the collector of the collector path (if one runs)."""
        self.source.close()

    def train(self, steps: int | None = None, run_dir=None) -> TrainResult:
        """Train until ``steps`` env steps per learner (default ``config.steps``).

        SIGINT (Ctrl-C) or SIGTERM ends the run after the current step: a checkpoint is written
        (with ``run_dir``) and the result says ``interrupted``; a second signal acts as usual.
        A signal during an evaluation ends it within a step (``partial_eval``, not on the curve)
        and the checkpoint is written.
        """
        cfg = self.config
        total = cfg.steps if steps is None else steps
        bar = progress_bar(
            cfg.progress, total=total, initial=self.step, unit="step", desc="train",
            dynamic_ncols=True,
        )  # fmt: skip
        with StopOnSignal() as stop:  # the final evaluation and save included
            while self.step < total and stop.signal is None:
                t0 = time.perf_counter()
                try:
                    self.train_step()
                except IndexError:  # an index out of range (CPU): the deferred check names it
                    raise_pending(self.deferred)
                    raise
                self.counters.train_seconds += time.perf_counter() - t0
                bar.update(self.E)
                self._after_step(cfg, run_dir)
            bar.close()
            raise_pending(self.deferred)
            if self.leaf_monitor is not None:
                self.leaf_monitor.warn()
            if self.eval_env is not None and stop.signal is None:
                if not self.curve or self.curve[-1][0] != self.step:
                    self._evaluate_and_log()
            if run_dir is not None:
                self.save(f"{run_dir}/checkpoint.pt")
        args = (
            self.history,
            self.step,
            self.counters.train_seconds,
            self.counters.real_steps,
            stop.signal,
        )
        return TrainResult.of(*args, eval_seconds=self.counters.eval_seconds)

    def _after_step(self, cfg: TrainConfig, run_dir) -> None:
        """Log, evaluate and checkpoint when their intervals are due (deferred checks first)."""
        nxt = self.counters.next
        log = self.step >= nxt["log"]
        ev = self.eval_env is not None and cfg.eval_every and self.step >= nxt["eval"]
        ckpt = run_dir is not None and cfg.checkpoint_every and self.step >= nxt["ckpt"]
        if log or ev or ckpt:
            raise_pending(self.deferred)  # (a due interval reads the device anyway)
        if log:
            self._log_training()
            nxt["log"] = self.step + cfg.log_every
        if ev:
            self._evaluate_and_log()
            nxt["eval"] = self.step + cfg.eval_every
        if ckpt:
            self.save(f"{run_dir}/checkpoint.pt")
            nxt["ckpt"] = self.step + cfg.checkpoint_every

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, learners=None) -> tuple[torch.Tensor, torch.Tensor]:
        """The evaluator's two numbers per learner ``[P]`` (episodic: return and success).

        (Mean episode lengths in ``last_eval_steps``, every episode in ``last_eval_records``.)
        ``learners`` (episodic only): evaluate just these; the others' numbers are NaN.
        """
        if learners is not None and not isinstance(self.evaluator, EpisodicEvaluator):
            raise ValueError("only the episodic evaluator evaluates some learners (learners=)")
        values = self.evaluator.evaluate(self, *(() if learners is None else (learners,)))
        self.last_eval_records = self.evaluator.last_records
        steps = self.evaluator.last_steps
        self.last_eval_steps = torch.full((self.P,), float("nan")) if steps is None else steps
        return values

    def evaluate_episodes(self) -> TensorDict:
        """One greedy episode per ``eval_env`` row, one record each (``EpisodicEvaluator``)."""
        return EpisodicEvaluator.episodes(self)

    def make_agent(self, env, stream: str, exploration=None, **options) -> HierarchicalAgent:
        """An agent over ``env``'s rows from the agent factory; random numbers: ``stream``."""
        exploration = self.exploration if exploration is None else exploration
        if self.config.check_leaf_rewards and self.learner.uses is not None:
            options.setdefault("uses", self.learner.uses | {"primitive"})  # the monitor reads
        return self.agents(
            self.graph, self.learner, exploration, env, stream, self.executor_config, **options
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
        self.counters.eval_seconds += self.eval_seconds
        cut = self.evaluator.last_partial  # a signal cut it short: logged, not on the curve
        if self.logger and self.last_eval_records is not None:
            records, loops = self.last_eval_records, self.evaluator.last_loops
            self.logger.log_episodes(self.step, records, self.graph.names, cut is not None, loops)
        values = mean.tolist()
        if self.logger or self.config.progress:  # the result as it happens (CLI runs)
            line = eval_line(self.step, self.evaluator.tags[0], values, self.eval_seconds)
            tqdm.write(line + self.evaluator.limit_note() + (f" (partial: {cut})" if cut else ""))
        if cut is not None:
            self.partial_eval = {"step": self.step, "signal": cut, "values": values}
            return
        self.history.record(
            self.step,
            values,
            success.tolist(),
            self.last_eval_steps.tolist(),
            self.counters.real_steps,
            self.config.threshold,
        )
        if self.logger:
            tags = self.evaluator.tags
            scalars = {tags[0]: values, tags[1]: self.history.last_success}
            scalars.update(self.evaluator.last_eval)  # e.g. its ratio
            scalars["perf/eval_seconds"] = [self.eval_seconds] * self.P
            self.logger.log(self.step, scalars)

    # ------------------------------------------------------------------ logging
    def _per_seed(self, counts: torch.Tensor) -> torch.Tensor:
        """Counters per table set summed per seed (``metrics.per_seed``)."""
        return metrics.per_seed(counts, self.P)

    def _log_training(self) -> None:
        if self.leaf_monitor is not None:
            self.leaf_monitor.warn()
        extra = self.evaluator.flush()
        if not self.logger:
            return
        scalars = self.episodes.flush()
        scalars.update(extra)
        scalars["perf/env_steps_per_s"] = [
            self.step * self.P / max(self.counters.train_seconds, 1e-9)
        ] * self.P
        skip, graph, P = self.executor_config.on_bad_step == "skip", self.graph, self.P
        subtasks, calls = metrics.subtask_metrics(
            graph, self.executor, self.learner, P, skip, self.step
        )
        scalars.update(subtasks)
        scalars.update(self.agents.training_metrics(self.graph, calls))
        metrics.reset_subtask_counters(self.executor, self.learner)
        self.logger.log(self.step, scalars)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """Everything needed to continue this run exactly."""
        return self.checkpointer.state_dict()

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``; on any mismatch nothing changes and ``CheckpointError`` rises."""
        self.checkpointer.load_state_dict(state)

    def save(self, path) -> None:
        """Write a checkpoint of this trainer (and of the run's configuration, if known)."""
        self.checkpointer.save(path, self.run_config)

    def load(self, path) -> None:
        """Continue from a checkpoint written by ``save``."""
        self.checkpointer.load(path)


def check_eval_env(env, eval_env) -> None:
    """An eval env has one learner per training learner (``ValueError`` otherwise)."""
    if eval_env is not None and eval_env.n_learners != env.n_learners:
        raise ValueError(
            f"the eval env has {eval_env.n_learners} learners (seeds), the training env "
            f"{env.n_learners}: build it with one seed per learner ([eval_seed] * "
            f"{env.n_learners}), eval_episodes rows each"
        )
