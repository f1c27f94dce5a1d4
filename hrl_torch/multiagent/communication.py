"""COM-Cooperative HRL's communication level (Section 6.5.2): validation, cost and messages.

``hrl_torch.multiagent.cooperative.Communication`` describes it; ``MultiAgentAgent`` builds one
``CommunicationLevel`` and asks it for the choice cost, the late and lost replies and the
messages of every step.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from hrl_torch.hierarchy.subtask import GraphError


class CommunicationLevel:
    """Validates a ``Communication``, builds its choice cost and records its messages."""

    def __init__(self, agent, communication) -> None:
        g, com, not_com = agent.graph, communication.com, communication.not_com
        for name in (com, not_com):
            if name not in g.index or g.node(name).is_primitive:
                raise GraphError(f"communication: {name!r} is not a subtask of the graph")
        cost = float(communication.cost)
        if not (cost >= 0.0 and cost < float("inf")):
            raise ValueError(f"communication cost must be finite and >= 0, got {cost}")
        if not 0.0 <= communication.loss <= 1.0:
            raise ValueError(f"communication loss must be in [0, 1], got {communication.loss}")
        if int(communication.delay) != communication.delay or communication.delay < 0:
            raise ValueError(f"communication delay must be an int >= 0, got {communication.delay}")
        self.loss, self.delay = float(communication.loss), int(communication.delay)
        self._history: torch.Tensor | None = None  # [delay + 1, B, n] own tasks, newest first
        level = next(
            (lv for k, lv in enumerate(agent.levels) if com in agent.cooperation.levels[k]), None
        )
        if level is None:
            raise GraphError(f"communication: {com!r} is not a cooperative subtask")
        if any(not_com in names for names in agent.cooperation.levels):
            raise GraphError(f"communication: {not_com!r} must not be cooperative")
        if set(g.node(com).children_names) != set(g.node(not_com).children_names):
            raise GraphError(f"communication: {com!r} and {not_com!r} need the same children")
        parents = [k for k, node in enumerate(g.nodes) if com in node.children_names]
        if parents != [k for k, node in enumerate(g.nodes) if not_com in node.children_names]:
            raise GraphError(f"communication: {com!r} and {not_com!r} need the same parents")
        self.agent, self.level, self.depth = agent, level, level.depth
        self.com = g.index[com]
        choice_cost = torch.zeros(g.n_nodes, g.node_children.shape[1])
        for k in parents:
            choice_cost[k, g.nodes[k].children_names.index(com)] = cost
        self.choice_cost = choice_cost.to(g.node_children.device)
        b, n = agent.executor.stack.batch_size[0], agent.n_agents
        dev = g.node_children.device
        self.count = torch.zeros(b, dtype=torch.long, device=dev)
        #: the replies of this step ``[B, n, n - 1]``: what ``com``'s choice reads
        self.replies = torch.full((b // n, n, max(n - 1, 0)), -1, dtype=torch.long, device=dev)
        self.messages = TensorDict(
            {"asked": torch.zeros(b // n, n, dtype=torch.bool, device=dev), "told": self.replies},
            batch_size=[b // n, n],
        )

    def restart(self) -> None:
        """A new start: no replies in flight."""
        self._history = None

    def late(self, own: torch.Tensor) -> torch.Tensor:
        """Every agent's task as the replies tell it: ``delay`` steps old (``own [B, n]``)."""
        if not self.delay:
            return own
        if self._history is None:  # the start: no older replies than the current tasks
            self._history = own.expand(self.delay + 1, *own.shape).clone()
        self._history = torch.cat([own[None], self._history[:-1]])
        return self._history[-1]

    def lose(self, others: torch.Tensor, rng) -> torch.Tensor:
        """``others [B, n, n - 1]`` with each reply lost (read as no task) with ``loss``."""
        if not self.loss:
            return others
        lost = rng.uniform(others.shape[2]).view(others.shape) < self.loss
        return torch.where(lost, self.level.none, others)

    def record(self) -> None:
        """After a step's pushes: the agents that invoked ``com`` asked (once per invocation)."""
        executor, n = self.agent.executor, self.agent.n_agents
        inst = executor.stack.inst[:, self.depth]
        node = torch.take(self.agent.graph.inst_node, inst.clamp_min(0))
        asked = executor.invoked[:, self.depth] & (node == self.com)
        self.count += asked
        members = torch.where(self.replies >= len(self.level.members), -1, self.replies)
        asked = asked.view(-1, n)
        self.messages = TensorDict(
            {"asked": asked, "told": torch.where(asked[..., None], members, -1)},
            batch_size=asked.shape,
        )
