"""One agent step, written once: context -> evaluate -> observe -> act -> update.

``HierarchicalAgent`` owns a task graph's executor (the Task-Stacks of ``B`` env rows), the
learner and the policy that turns the learner's values into choices. ``start(obs)`` puts the
root on every stack and returns the first actions; ``step(td)`` takes the env's output for
those actions and

1. computes the graph's context (abstract states, termination, available children),
2. lets the learner evaluate the values its choices and targets need (``learner.evaluate``),
3. pops what ended and collects the finished SMDP transitions (``executor.observe``),
4. pushes children until a primitive is on top and takes the next actions (``executor.act``),
5. updates the learner from the transitions (``learner.update``, training agents only).

Steps 1-4 (``decide``) read the learned tables and never change them, so the acting part can
run as a TorchRL policy whose frames carry the transitions, and the update can run on those
frames (``hrl_torch.training.collector``); the direct loop and the collector path learn the same
tables. The choices of a step see the tables before that step's update.

The trainer, its greedy evaluation, the continuing-task evaluator, the TorchRL collector path
and the scripts all step through this class.
"""

from __future__ import annotations

from typing import Protocol

import torch
from tensordict import TensorDict

from hrl_torch.common.ops import put
from hrl_torch.common.rng import BatchRNG
from hrl_torch.execution.executor import ExecutorConfig, HierarchicalExecutor
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.learners.base import Learner, ValuePolicy
from hrl_torch.modules.exploration import Exploration

#: key of the learner's values at ``s'`` in a transition batch (what ``evaluate`` computed)
VALUES = "values"
#: key of the observation ``s'`` in a transition batch
OBS = "obs"


def with_values(batch: TensorDict, ctx: StepContext) -> TensorDict:
    """``batch`` with the learner's values at ``s'`` (``VALUES``) and ``s'`` (``OBS``) set.

    What ``learner.update`` reads besides the transitions; ``ctx`` is the context the
    transitions end in, after ``learner.evaluate(ctx)``.
    """
    b = torch.Size([batch.batch_size[0]])
    put(batch, VALUES, TensorDict._new_unsafe(ctx.values, batch_size=b))
    put(batch, OBS, ctx.obs)
    return batch


class FrozenValues:
    """A learner's values at every (learner, state) of a tabulated graph, evaluated once.

    A non-learning agent (a greedy evaluation) steps frozen tables many times; when the
    learner's values are a function of a row's learner and state (``values_per_state``, a
    tabulated graph), one ``learner.evaluate`` over all of them and one ``index_select`` per
    value and step give the numbers ``learner.evaluate`` would (each row's arithmetic is the
    same). Build it anew whenever the tables change.
    """

    def __init__(self, graph: TaskGraph, learner: Learner) -> None:
        n_states = graph.tab_abstract.shape[0]
        device = graph.tab_abstract.device
        states = torch.arange(n_states, device=device).repeat(learner.n_learners)
        owner = torch.arange(learner.n_learners, device=device).repeat_interleave(n_states)
        obs = graph.table_observations.to(device)[states]  # (every field, for ``ctx.obs``)
        ctx = graph.context(obs, owner)
        learner.evaluate_checked(ctx)
        self.values = ctx.values
        self.n_states = n_states

    @classmethod
    def build(cls, graph: TaskGraph, learner: Learner, max_rows: int) -> FrozenValues | None:
        """``FrozenValues`` if the learner and graph allow it within ``max_rows`` rows."""
        if not learner.values_per_state or graph.table_key is None:
            return None
        if learner.n_learners * graph.tab_abstract.shape[0] > max_rows:
            return None
        return cls(graph, learner)

    def fill(self, ctx: StepContext) -> None:
        """``ctx.values`` at ``ctx``'s rows (tensors shared between keys stay shared)."""
        row = ctx.learner * self.n_states + ctx.table_row
        looked_up: dict[int, torch.Tensor] = {}
        for key, value in self.values.items():
            if id(value) not in looked_up:
                looked_up[id(value)] = value.index_select(0, row)
            ctx.values[key] = looked_up[id(value)]


def make_policy(learner: Learner, exploration: Exploration, rng: BatchRNG, evaluate: bool = False):
    """The executor policy of ``learner`` (``Learner.make_policy``; values by default).

    Policy-gradient and hybrid learners supply their own policy (PG nodes sample from their
    heads); ``evaluate`` asks for the evaluation policy (PG nodes act on their modes). Value
    learners choose with ``exploration`` over their action values (``ValuePolicy``).
    """
    return learner.make_policy(exploration, rng, evaluate=evaluate)


class HierarchicalAgent:
    """A learner acting through the Task-Stacks of ``batch_size`` env rows.

    Args:
        graph: the task graph.
        learner: the population learner (row ``b`` belongs to learner ``b // E``).
        exploration: how value nodes choose (``Greedy()`` to evaluate).
        rng: random numbers of the rows' choices.
        envs_per_learner: ``E``.
        executor_config: guard and all-states options.
        learn: update the learner at every step (training); otherwise only act.
        evaluate: act with the evaluation policy (PG nodes on their modes, nothing recorded).
        transitions: return the SMDP transitions from ``step`` (default: ``learn``).
        rows: the learner of each row ``[B]`` instead of ``b // E`` (multi-agent rows).
        uses: the optional transition keys to compute (``HierarchicalExecutor.OPTIONAL``;
            default: the learner's ``uses``, or all when it has none).

    Attributes:
        clock: env steps per learner, the clock of the learner's schedules (exploration, step
            sizes); a learning agent advances it by ``E`` per step.
        ctx: the context of the latest observations; ``batch``: the latest transitions.
    """

    def __init__(
        self,
        graph: TaskGraph,
        learner: Learner,
        exploration: Exploration,
        rng: BatchRNG,
        envs_per_learner: int,
        executor_config: ExecutorConfig | None = None,
        learn: bool = True,
        evaluate: bool = False,
        transitions: bool | None = None,
        rows: torch.Tensor | None = None,
        uses: frozenset[str] | None = None,
    ) -> None:
        self.graph, self.learner = graph, learner
        self.learn = learn
        self.transitions = learn if transitions is None else transitions
        self.policy = make_policy(learner, exploration, rng, evaluate)
        self.executor = HierarchicalExecutor(
            graph,
            rng.batch_size,
            envs_per_learner,
            learner.gamma,
            executor_config,
            learner=rows,
            score_width=0 if evaluate else learner.score_width,
            uses=learner.uses if uses is None else uses,
            count_stats=learn,  # (nobody reads an evaluation's subtask statistics)
            sums=self.transitions,  # (nor its reward sums, without transitions)
        )
        self.rows = self.executor.learner
        learner.know_rows(self.rows, self.executor.row_layout)
        self._made = {"exploration": exploration, "config": executor_config, "evaluate": evaluate}
        self.clock = 0
        self.device_clock: torch.Tensor | None = None  # (``count_on_device``)
        self.ctx: StepContext | None = None
        self.batch: TensorDict | None = None
        self.frozen: FrozenValues | None = None

    #: freeze only when evaluating every state costs at most this share of evaluating the
    #: rows at every step of the run (the one-off evaluation costs about a step over that
    #: many rows)
    FREEZE_SHARE = 1 / 8

    def freeze_values(self, steps: int) -> bool:
        """Evaluate the learner's values at every state once and look them up from now on.

        For a run of at most ``steps`` steps of an agent that does not learn (a greedy
        evaluation), on a tabulated graph whose learner allows it (``FrozenValues``), when
        the states of all learners number at most ``FREEZE_SHARE`` of rows x ``steps``.
        Returns whether it did; the tables must not change while the agent uses the values.
        """
        if self.learn:
            raise RuntimeError("a learning agent cannot freeze its values")
        max_rows = int(self.executor.batch_size * steps * self.FREEZE_SHARE)
        self.frozen = FrozenValues.build(self.graph, self.learner, max_rows)
        return self.frozen is not None

    def subset(self, rows: torch.Tensor) -> HierarchicalAgent:
        """A non-learning agent over the rows ``rows`` only, in their current state.

        Their Task-Stacks, last actions and random streams carry over, so each row goes on
        exactly as here (greedy evaluation stops stepping finished rows with it). Value-based
        learners only (``ValuePolicy``); ``None`` for others.
        """
        if type(self.policy) is not ValuePolicy or self.learn:
            return None
        sub = HierarchicalAgent(
            self.graph,
            self.learner,
            self._made["exploration"],
            self.policy.rng.subset(rows),
            self.envs_per_learner,
            self._made["config"],
            learn=False,
            evaluate=self._made["evaluate"],
            transitions=False,
            rows=self.rows[rows],
        )
        sub.executor.continue_rows(self.executor, rows)
        sub.clock = self.clock
        sub.frozen = self.frozen
        return sub

    @property
    def envs_per_learner(self) -> int:
        """Rows per learner ``E`` (the clock advances by ``E`` per learning step)."""
        return self.executor.envs_per_learner

    def context(self, obs: TensorDict, values: bool = True) -> StepContext:
        """The graph's context at ``obs``, with the learner's values in ``ctx.values``.

        ``values=False``: without them (``evaluated`` adds them later).
        """
        ctx = self.graph.context(obs, self.rows, self.executor.memory)
        return self.evaluated(ctx) if values else ctx

    def evaluated(self, ctx: StepContext) -> StepContext:
        """``ctx`` with the learner's values (looked up where they are frozen)."""
        if self.frozen is not None:
            self.frozen.fill(ctx)
        else:
            self.learner.evaluate_checked(ctx)
        self.ctx = ctx
        return ctx

    def start(self, obs: TensorDict) -> torch.Tensor:
        """Empty every stack, start at the root and return the first actions ``[B]``."""
        self.executor.reset()
        return self.executor.act(self.context(obs), self.policy, self.schedule_clock)

    def decide(self, td: TensorDict) -> tuple[torch.Tensor, TensorDict | None]:
        """Steps 1-4 on the env's output ``td``: ``(next actions [B], transitions)``.

        The transitions carry the learner's values at ``s'`` (``VALUES``) and ``s'`` itself
        (``OBS``): all ``learner.update`` needs. Nothing learned changes.
        """
        ctx = self.context(td)
        batch = self.executor.observe(td, ctx, transitions=self.transitions)
        action = self.executor.act(ctx, self.policy, self.schedule_clock)
        if batch is not None:
            with_values(batch, ctx)
        self.batch = batch
        return action, batch

    def update(self, batch: TensorDict) -> None:
        """Step 5: learn from one step's transitions; the clock advances by ``E``."""
        self.learner.update_checked(batch, self.schedule_clock)
        self.clock += self.executor.envs_per_learner
        if self.device_clock is not None:
            self.device_clock.add_(self.executor.envs_per_learner)

    @property
    def schedule_clock(self) -> int | torch.Tensor:
        """What the schedules read: ``clock``, or its copy on the device (``count_on_device``)."""
        return self.clock if self.device_clock is None else self.device_clock

    def count_on_device(self) -> None:
        """Hand the schedules the clock as a device tensor from now on (same values).

        A replayed step reads it; ``update`` moves it on in place.
        """
        if self.device_clock is None:
            dev = self.rows.device
            self.device_clock = torch.tensor(self.clock, dtype=torch.int64, device=dev)

    def step(self, td: TensorDict) -> torch.Tensor:
        """One turn of the loop on the env's output ``td``; returns the next actions ``[B]``."""
        action, batch = self.decide(td)
        if self.learn:
            self.update(batch)
        return action


class AgentFactory(Protocol):
    """Builds a run's agents (training and evaluation) over an env's rows.

    ``Trainer`` takes one: ``SingleAgentFactory`` (the default) or, for a multi-agent env,
    ``hrl_torch.multiagent.factory.MultiAgentFactory``.

    Attributes:
        n_agents: agents per env row (``None``: one agent per row, a single-agent env).
    """

    n_agents: int | None

    def __call__(
        self,
        graph: TaskGraph,
        learner: Learner,
        exploration: Exploration,
        env,
        stream: str,
        executor_config: ExecutorConfig,
        **options,
    ) -> HierarchicalAgent:
        """An agent over ``env``'s rows; its random numbers are the stream ``stream``."""
        ...

    def table_sets(self, n_learners: int) -> int:
        """Table sets the learner needs for ``n_learners`` seeds."""
        ...

    def training_metrics(self, graph: TaskGraph, calls: torch.Tensor) -> dict[str, list[float]]:
        """Metrics of these agents at a log (``calls [P, n_nodes]``: calls per seed)."""
        ...


class SingleAgentFactory:
    """``HierarchicalAgent``s: one agent per env row."""

    n_agents = None

    def __call__(self, graph, learner, exploration, env, stream, executor_config, **options):
        """An agent over ``env``'s rows (``AgentFactory``)."""
        e = env.envs_per_learner
        rng = BatchRNG(env.seeds, e, stream, device=env.device)
        return HierarchicalAgent(graph, learner, exploration, rng, e, executor_config, **options)

    def table_sets(self, n_learners: int) -> int:
        """One table set per seed."""
        return n_learners

    def training_metrics(self, graph, calls) -> dict[str, list[float]]:
        """None."""
        return {}


def checked_factory(factory: AgentFactory | None, env, learner: Learner, graph) -> AgentFactory:
    """The agent factory; a ``ValueError`` unless the learner fits ``graph`` and the agents."""
    shape = [(n.name, n.n_states) for n in graph.nodes]
    if [(n.name, n.n_states) for n in learner.graph.nodes] != shape:
        raise ValueError("the learner was built on another task graph (nodes or their states)")
    if factory is None:
        if env.n_agents is not None:
            raise ValueError(
                "a multi-agent env needs agent_factory="
                "hrl_torch.multiagent.factory.MultiAgentFactory(env.n_agents, config)"
            )
        factory = SingleAgentFactory()
    sets = factory.table_sets(env.n_learners)
    if learner.n_learners != sets:
        raise ValueError(f"learner has {learner.n_learners} table sets, the env needs {sets}")
    return factory
