"""A fixed rule as a learner that learns nothing: baselines such as dispatching rules.

``RuleLearner`` runs on a flat graph (the root over the primitive actions) whose children are
chosen by a rule: a callable from the observations of the rows to env actions ``[B]``. The
trainer, its evaluation, logging and checkpoints treat it like any learner, so a rule's curve
sits beside the learners' in the same run folder format. A rule may keep memory across steps
(a dispatcher's assignments): ``make_rule(batch_size)`` builds one rule per agent (the training
agent's and each evaluation's), and the training rule's ``state_dict`` is checkpointed with the
learner when it has one.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from hrl_torch.common.checkpoint import Stateful
from hrl_torch.common.devices import attributes_of, move_attributes
from hrl_torch.execution.transitions import Choice
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.base import Learner

Rule = Callable[[object], torch.Tensor]


class RuleLearner(Learner):
    """A rule choosing the root's primitive children (see the module docstring).

    Args:
        graph: a flat graph: every child of the root is a primitive.
        n_learners: population size (tables: none).
        make_rule: ``make_rule(n_rows) -> rule`` with ``rule(obs TensorDict [n_rows]) ->
            env actions [n_rows]``.
    """

    def __init__(self, graph: TaskGraph, n_learners: int, make_rule: Callable[[int], Rule]) -> None:
        super().__init__(graph, n_learners)
        root = graph.root
        kids = graph.node_children[root, : int(graph.node_n_children[root])]
        if not bool(graph.node_is_primitive[kids].all()):
            raise GraphError("a rule chooses primitives: every child of the root must be one")
        slot = torch.full((int(graph.node_action.max()) + 1,), -1, dtype=torch.long)
        slot[graph.node_action[kids]] = torch.arange(len(kids))
        self.register_buffer("slot_of_action", slot, persistent=False)
        self.make_rule = make_rule
        self._training_rule = None

    def make_policy(self, exploration, rng, evaluate: bool = False) -> RulePolicy:
        """The rule over ``rng``'s rows (exploration is the rule's own business)."""
        rule = self.make_rule(rng.batch_size)
        if attributes_of(rule) is not None:  # (its memory on the rows' device)
            move_attributes(rule, lambda t: t.to(rng.device))
        if not evaluate:
            self._training_rule = rule
        return RulePolicy(self, rule, rng)

    def update(self, batch, step: int) -> None:
        """Nothing to learn."""

    def get_extra_state(self) -> dict:
        """The training rule's memory (when it has any)."""
        rule = self._training_rule
        return rule.state_dict() if isinstance(rule, Stateful) else {}

    def set_extra_state(self, state: dict) -> None:
        """Restore ``get_extra_state`` into the training rule."""
        if state and self._training_rule is not None:
            self._training_rule.load_state_dict(state)


class RulePolicy:
    """Executor policy of a ``RuleLearner``: the rule's action as the root's child."""

    def __init__(self, learner: RuleLearner, rule: Rule, rng) -> None:
        self.learner, self.rule, self.rng = learner, rule, rng

    def new_step(self) -> None:
        """Nothing to draw."""

    def select(self, inst, ctx: StepContext, available, step: int, push: int) -> Choice:
        """The rule's actions, as child slots of the root."""
        slot = torch.take(self.learner.slot_of_action, self.rule(ctx.obs))
        return Choice(slot, torch.ones_like(slot, dtype=torch.bool))
