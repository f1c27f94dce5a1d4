"""One agent step, written once: context -> evaluate -> observe -> update -> act.

``HierarchicalAgent`` owns a task graph's executor (the Task-Stacks of ``B`` env rows), the
learner and the policy that turns the learner's values into choices. ``start(obs)`` puts the
root on every stack and returns the first actions; ``step(td)`` takes the env's output for
those actions and

1. computes the graph's context (abstract states, termination, available children),
2. lets the learner evaluate the values its choices and targets need (``learner.evaluate``),
3. pops what ended and collects the finished SMDP transitions (``executor.observe``),
4. updates the learner from them (``learner.update``, training agents only),
5. pushes children until a primitive is on top and returns the next actions
   (``executor.act``).

The trainer, its greedy evaluation, the continuing-task evaluator, the TorchRL collector path
and the scripts all step through this one method.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from hrl_torch.executor import ExecutorConfig, HierarchicalExecutor
from hrl_torch.exploration import Exploration
from hrl_torch.graph import StepContext, TaskGraph
from hrl_torch.learners.base import Learner, ValuePolicy
from hrl_torch.rng import BatchRNG


def make_policy(learner: Learner, exploration: Exploration, rng: BatchRNG, evaluate: bool = False):
    """The executor policy of ``learner``: its own ``make_policy`` if it has one, else values.

    Policy-gradient and hybrid learners supply their own policy (PG nodes sample from their
    heads); ``evaluate`` asks for the evaluation policy (PG nodes act on their modes). Value
    learners choose with ``exploration`` over their action values (``ValuePolicy``).
    """
    make = getattr(learner, "make_policy", None)
    if make is not None:
        return make(exploration, rng, evaluate=evaluate)
    return ValuePolicy(learner, exploration, rng)


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
    ) -> None:
        self.graph, self.learner = graph, learner
        self.learn = learn
        self.transitions = learn if transitions is None else transitions
        self.executor = HierarchicalExecutor(
            graph, rng.batch_size, envs_per_learner, learner.gamma, executor_config
        )
        self.policy = make_policy(learner, exploration, rng, evaluate)
        self.rows = self.executor.learner
        self.clock = 0
        self.ctx: StepContext | None = None
        self.batch: TensorDict | None = None

    def context(self, obs: TensorDict) -> StepContext:
        """The graph's context at ``obs``, with the learner's values in ``ctx.values``."""
        ctx = self.graph.context(obs, self.rows, self.executor.memory)
        self.learner.evaluate(ctx)
        self.ctx = ctx
        return ctx

    def start(self, obs: TensorDict) -> torch.Tensor:
        """Empty every stack, start at the root and return the first actions ``[B]``."""
        self.executor.reset()
        return self.executor.act(self.context(obs), self.policy, self.clock)

    def step(self, td: TensorDict) -> torch.Tensor:
        """One turn of the loop on the env's output ``td``; returns the next actions ``[B]``."""
        ctx = self.context(td)
        self.batch = self.executor.observe(td, ctx, transitions=self.transitions)
        if self.learn:
            self.learner.update(self.batch, ctx, self.clock)
            self.clock += self.executor.envs_per_learner
        return self.executor.act(ctx, self.policy, self.clock)
