"""Hierarchical multi-agent learning (Chapter 6): agents as rows, cooperative subtasks, schemes.

``n`` agents share every env row of a ``MultiAgentBatchedEnv``; each runs its own copy of one
task graph on its *agent row* (``hrl_torch.env.multiagent_env.agent_rows``: row ``b * n + j`` is
agent ``j`` of env row ``b``), so the ``B * n`` agents are rows of one batched executor, not a
Python loop. ``MultiAgentAgent`` is a ``HierarchicalAgent`` over those rows; its ``start`` and
``decide`` take and return env-level steps (actions ``[B, n]``), so the ``Trainer`` drives it
like any agent. Every agent learns its own tables (``C^j``, Section 6.3): the learner of agent
row ``b * n + j`` is ``p * n + j`` with ``p`` the row's seed, so a learner for ``P`` seeds has
``P * n`` table sets (``shared_tables=True``: one set per seed, shared by its agents).

**Cooperative subtasks** (Section 6.2, Definition 6.4). ``Cooperation`` lists, per cooperation
level, the cooperative subtasks; ``U_l`` is the union of their children. A cooperative
subtask's abstract state is extended by the *other* agents' current ``U_l`` subtasks:
``s * K + code`` with ``code`` the others' ``U_l`` indices in radix ``|U_l|`` (``K =
|U_l|^(n-1)``), so its completion table is the joint completion ``C^j(i, s, a^1, ..., a^n)``
of Equation 6.1 and the unchanged two-part learners (MAXQ-Q here) learn Equation 6.3: the
state where a child started carries the others' actions then, ``s'`` the others' actions at
its end (Algorithm 4's ``Seq``; with all-states updating every visited state carries the
actions at that state). The others' actions are read from their Task-Stacks; agents that
choose at the same step choose in agent order, each seeing the earlier ones' fresh choices
(``Cooperation.broadcast``, ``hrl_torch.multiagent.broadcast``; ``"simultaneous"``: the Task-Stacks
of the previous step, so choices at the same epoch do not see each other). An agent with no
``U_l`` subtask (at a reset, or whose subtask just ended) counts as doing
``Cooperation.idle``. The projected value ``V(a, s)`` a cooperative parent reads from a
cooperative child is the child's value at the others' current actions (the text marginalizes
over them; conditioning uses what the agent knows).

**Termination schemes** (Section 6.1) at the first cooperation level:

- ``"continue"`` (tau_continue, the text's choice): an agent whose ``U_l`` subtask ends
  chooses a new one; the others go on.
- ``"any"`` (tau_any): when one agent's ``U_l`` subtask ends, every other agent's ``U_l``
  subtask is interrupted (at that agent's next decision epoch: in an event-driven env an agent
  in the middle of a primitive action finishes it first) and all choose anew. An interrupted
  subtask teaches no completion value (as any aborted child).
- ``"all"`` (tau_all): an agent whose ``U_l`` subtask ends waits (the cooperative subtask's
  ``wait`` child, forced) until no other agent runs a ``U_l`` subtask but ``wait``; then they
  choose together.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import torch
from tensordict import TensorDict

from hrl_torch.common.rng import BatchRNG
from hrl_torch.env.multiagent_env import agent_rows
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.execution.transitions import Choice, PricesChoices, as_choice
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Subtask
from hrl_torch.learners.base import Learner
from hrl_torch.modules.exploration import Exploration
from hrl_torch.multiagent.broadcast import choose_in_order
from hrl_torch.multiagent.communication import CommunicationLevel
from hrl_torch.training.agent import HierarchicalAgent, with_values

Scheme = Literal["continue", "any", "all"]
Broadcast = Literal["sequential", "simultaneous"]


@dataclass(frozen=True)
class Communication:
    """A communication level of COM-Cooperative HRL (Section 6.5, Figure 6.9).

    Below a cooperation level's parent sit two siblings with the same children: ``com``
    (Communicate: a cooperative subtask of a ``Cooperation`` level, so its completions are
    joint, indexed by the other agents' ``U_l`` tasks it asks for) and ``not_com``
    (Not-Communicate: plain completions, a selfish choice). Their parent chooses by comparing
    ``Q(parent, s, com) - cost`` with ``Q(parent, s, not_com)``: the text's "``Q(Parent(Com),
    s, Com) + ComCost``" with the cost written as a positive number. The cost biases that
    choice only; it is not a reward (the text's figures report throughput and waiting time
    without it), so the learned values are those of the behaviour. ``com`` and ``not_com``
    need no termination of their own: the agent cuts them when their ``U_l`` child ends, so
    every ``U_l`` decision is preceded by a communication decision (tau_continue only).

    Beyond the text (its future work): replies can be lost or late. A lost reply reads as
    "no task" (``Cooperation.idle`` when given), each with probability ``loss`` per step and
    other agent; a late one tells the other agent's task of ``delay`` steps ago.

    Attributes:
        com: the Communicate subtask.
        not_com: the Not-Communicate subtask.
        cost: ComCost, ``>= 0``, paid once per communication (each invocation of ``com``).
        loss: probability in ``[0, 1]`` that one reply is lost.
        delay: steps ``>= 0`` by which a reply is late.
    """

    com: str = "Com"
    not_com: str = "NotCom"
    cost: float = 0.0
    loss: float = 0.0
    delay: int = 0


@dataclass(frozen=True)
class Cooperation:
    """Cooperative subtasks, one tuple of names per cooperation level (top level first).

    Attributes:
        levels: the cooperative subtasks of each cooperation level; the subtasks of one level
            must sit at one depth of the task graph.
        idle: the member of ``U_l`` an agent without a ``U_l`` subtask counts as (``None``:
            a code of its own, ``|U_l| + 1`` values per other agent).
        wait: the child a waiting agent takes under tau_all (a member of ``U_1``).
        broadcast: how agents that choose at the same step see each other's choices.
            ``"sequential"`` (default; the text's broadcast rule, Section 6.5: an agent's
            choice is known to the team as soon as it is made): they choose in agent order,
            each seeing the fresh ``U_l`` choices of the agents before it
            (``hrl_torch.multiagent.broadcast``). ``"simultaneous"`` (the behaviour before): each
            sees the others' ``U_l`` subtasks of the previous step, a just-ended one included.
    """

    levels: tuple[tuple[str, ...], ...]
    idle: str | None = None
    wait: str | None = None
    broadcast: Broadcast = "sequential"


class CooperativeSubtask(Subtask):
    """A subtask whose abstract state also says what the other agents do in ``U_l``.

    ``abstract(obs) = base.abstract(obs) * K + obs[key]``; every other predicate is the base
    subtask's. ``key`` is the observation field ``MultiAgentAgent`` fills with the others'
    ``U_l`` code in ``[0, K)``.
    """

    def __init__(self, base: Subtask, key: str, n_codes: int) -> None:
        super().__init__(base.name, base.children_names, base.n_states * n_codes)
        self.base, self.key, self.n_codes = base, key, int(n_codes)
        self.n_features = base.n_features
        self.memory_size = base.memory_size
        self.event_termination = base.event_termination

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        """The base state times ``K`` plus the others' ``U_l`` code."""
        return self.base.abstract(obs) * self.n_codes + obs[self.key]

    def terminated(self, obs, memory=None):
        """The base subtask's termination."""
        return self.base.terminated(obs, memory) if self.memory_size else self.base.terminated(obs)

    def initiable(self, obs):
        """The base subtask's initiation set."""
        return self.base.initiable(obs)

    def child_mask(self, obs):
        """The base subtask's available children."""
        return self.base.child_mask(obs)

    def pseudo_reward(self, obs, memory=None):
        """The base subtask's pseudo reward."""
        return self.base.pseudo_reward(obs, memory)

    def shaping_reward(self, obs, action, next_obs, memory=None):
        """The base subtask's shaping reward."""
        if self.memory_size:
            return self.base.shaping_reward(obs, action, next_obs, memory)
        return self.base.shaping_reward(obs, action, next_obs)

    def features(self, obs, memory=None):
        """The base subtask's features."""
        return self.base.features(obs, memory)

    def remember(self, obs):
        """The base subtask's invocation memory."""
        return self.base.remember(obs)

    def has_internal_rewards(self) -> bool:
        """Whether the base subtask has internal rewards."""
        return self.base.has_internal_rewards()

    def has_shaping_rewards(self) -> bool:
        """Whether the base subtask has shaping rewards (this wrapper adds none)."""
        return self.base.has_shaping_rewards()


@dataclass
class _Level:
    """One cooperation level: its depth, ``U_l``, the code of each node and the obs key."""

    depth: int
    members: list[str]
    code_of_node: torch.Tensor  # [n_nodes]: index in U_l, or ``none`` for other nodes
    none: int  # the code of an agent without a U_l subtask
    radix: int  # values per other agent
    key: str
    code_of_inst_1: torch.Tensor | None = None  # (``MultiAgentAgent``: per instance + 1)
    weights: torch.Tensor | None = None  # (``MultiAgentAgent``: radix ** rank, ``[n - 1]``)


def cooperative_graph(graph: TaskGraph, cooperation: Cooperation, n_agents: int) -> TaskGraph:
    """``graph`` with the cooperative subtasks of ``cooperation`` made joint.

    See the module docstring; an unknown subtask name, or a level whose subtasks sit at several
    depths, is a ``GraphError``.
    """
    levels = cooperation_levels(graph, cooperation, n_agents)
    nodes = list(graph.nodes)
    for k, level_names in enumerate(cooperation.levels):
        for name in level_names:
            i = graph.index[name]
            codes = levels[k].radix ** (n_agents - 1)
            nodes[i] = CooperativeSubtask(nodes[i], levels[k].key, codes)
    return TaskGraph(graph.root_name, nodes, graph.n_actions)


def cooperation_levels(graph: TaskGraph, cooperation: Cooperation, n_agents: int) -> list[_Level]:
    """The cooperation levels of ``graph`` (validated)."""
    levels = []
    for k, names in enumerate(cooperation.levels):
        unknown = [n for n in names if n not in graph.index]
        if unknown:
            raise GraphError(f"cooperation level {k} names unknown subtasks {unknown}")
        if any(graph.node(n).is_primitive for n in names):
            raise GraphError(f"cooperation level {k}: a primitive cannot be cooperative")
        depths = {
            int(d)
            for n in names
            for d in graph.host("inst_depth")[graph.host("inst_node") == graph.index[n]].tolist()
        }
        if len(depths) != 1:
            raise GraphError(f"cooperation level {k}: its subtasks sit at depths {sorted(depths)}")
        members = list(dict.fromkeys(c for n in names for c in graph.node(n).children_names))
        idle = cooperation.idle if k == 0 else None
        if idle is not None and idle not in members:
            raise GraphError(f"Cooperation.idle {idle!r} is not in U_{k + 1} {members}")
        none = members.index(idle) if idle is not None else len(members)
        code = torch.full((graph.n_nodes,), none, dtype=torch.long)
        for u, name in enumerate(members):
            code[graph.index[name]] = u
        radix = len(members) + (idle is None)
        levels.append(_Level(depths.pop(), members, code, none, radix, f"others_U{k + 1}"))
    if cooperation.wait is not None and (not levels or cooperation.wait not in levels[0].members):
        raise GraphError(f"Cooperation.wait {cooperation.wait!r} is not in U_1")
    if cooperation.broadcast not in ("sequential", "simultaneous"):
        raise ValueError(
            f"Cooperation.broadcast must be 'sequential' or 'simultaneous', "
            f"got {cooperation.broadcast!r}"
        )
    return levels


class MultiAgentAgent(HierarchicalAgent):
    """``n`` agents per env row as rows of one hierarchical agent (see the module docstring).

    Args:
        graph: the task graph of one agent (``cooperative_graph`` for cooperation).
        learner: the population learner, ``P * n`` table sets (or ``P`` with
            ``shared_tables``).
        exploration: how value nodes choose.
        rng: random numbers of the ``B * n`` agent rows (``BatchRNG(seeds, E * n, ...)``).
        envs_per_learner: env rows ``E`` per seed (the clock advances by ``E`` per step).
        n_agents: agents per env row.
        executor_config: guard and all-states options.
        learn / evaluate / transitions: as ``HierarchicalAgent``.
        cooperation: the cooperative subtasks (``None``: selfish agents).
        scheme: termination scheme at the first cooperation level.
        shared_tables: the agents of a seed share one table set.
        communication: COM-Cooperative HRL's communication level (``None``: none).
        first_table: act with the table sets from this one on (one seed of a trained
            population: ``seed * n``); ``None``: the learner has exactly the sets needed.
    """

    def __init__(
        self,
        graph: TaskGraph,
        learner: Learner,
        exploration: Exploration,
        rng: BatchRNG,
        envs_per_learner: int,
        n_agents: int,
        executor_config: ExecutorConfig | None = None,
        learn: bool = True,
        evaluate: bool = False,
        transitions: bool | None = None,
        cooperation: Cooperation | None = None,
        scheme: Scheme = "continue",
        shared_tables: bool = False,
        first_table: int | None = None,
        communication: Communication | None = None,
    ) -> None:
        if scheme not in ("continue", "any", "all"):
            raise ValueError(f"scheme must be 'continue', 'any' or 'all', got {scheme!r}")
        self.n_agents = n = int(n_agents)
        b = rng.batch_size
        rows = _table_sets_of_rows(rng, envs_per_learner, n, learner, shared_tables, first_table)
        super().__init__(
            graph,
            learner,
            exploration,
            rng,
            envs_per_learner,
            executor_config,
            learn,
            evaluate,
            transitions,
            rows=rows,
        )
        self.cooperation = cooperation
        self.levels = cooperation_levels(graph, cooperation, n) if cooperation else []
        self.scheme = scheme
        if scheme != "continue" and not self.levels:
            raise ValueError(f"scheme {scheme!r} needs a cooperation level")
        dev = graph.node_children.device
        others = [[k for k in range(n) if k != j] for j in range(n)]
        #: ``[n, n - 1]``: the other agents of each agent, in index order
        self.other_agents = torch.tensor(others, dtype=torch.long, device=dev).view(n, n - 1)
        #: ``[n, n - 1]``: whether each of those comes before the agent (``broadcast``)
        self.earlier_others = self.other_agents < torch.arange(n, device=dev)[:, None]
        inst_node = graph.inst_node.to(dev)
        for level in self.levels:
            level.code_of_node = level.code_of_node.to(dev)
            #: per instance + 1 (0: none) its node's code, and the others' place values
            none = torch.full((1,), level.none, dtype=torch.long, device=dev)
            level.code_of_inst_1 = torch.cat([none, level.code_of_node[inst_node]])
            level.weights = level.radix ** torch.arange(n - 1, device=dev)
        self._pending = torch.zeros(b, dtype=torch.bool, device=dev)  # tau_any interruptions
        if scheme == "any":
            self.executor.interrupt = self._interrupt
        if scheme == "all" and cooperation.wait is None:
            raise ValueError("scheme 'all' needs Cooperation.wait (the waiting child)")
        self.communication = communication
        if communication is not None:
            if scheme != "continue":
                raise ValueError("communication runs with the 'continue' scheme only")
            self._com = CommunicationLevel(self, communication)
            self.executor.interrupt = self._end_communication
        self.set_policy(self.policy)
        self._init_broadcast(cooperation, communication)

    def _init_broadcast(self, cooperation, communication) -> None:
        """Set up the broadcast rule (``Cooperation.broadcast``).

        Agents choose in index order within a step; a communicating level keeps its replies.
        """
        self._in_order = bool(self.levels) and cooperation.broadcast == "sequential"
        #: every agent's ``U_l`` codes after this step's pops, per level ``[B, n]``
        self.epoch_codes: list[torch.Tensor] | None = None
        self._fixed_levels = {
            k: True
            for k, names in enumerate(cooperation.levels if cooperation else ())
            if communication is not None and communication.com in names
        }
        #: per level ``[n_nodes]`` long: 1 at its cooperative subtasks (``broadcast.recoded``)
        self.code_columns: list[torch.Tensor] = []
        for names in cooperation.levels if cooperation else ():
            hit = torch.tensor([name in names for name in self.graph.names], dtype=torch.long)
            self.code_columns.append(hit.to(self.graph.node_children.device))

    def set_policy(self, policy) -> None:
        """Act with ``policy`` (under tau_all wrapped so that finished agents wait)."""
        if self.communication is not None:
            if not isinstance(policy, PricesChoices):
                raise ValueError("communication needs a value-based policy (ValuePolicy)")
            policy.choice_cost = self._com.choice_cost
        self.policy = _WaitPolicy(self, policy) if self.scheme == "all" else policy

    # ------------------------------------------------------------------ env <-> agent rows
    def start(self, obs: TensorDict) -> torch.Tensor:
        """Every agent starts at the root; the first actions ``[B, n]``."""
        self._pending.zero_()
        if self.communication is not None:
            self._com.restart()
        if self._in_order:
            self.executor.reset()
            action, _ = choose_in_order(self, self._rows(obs), self._fixed_levels)
        else:
            action = super().start(self._rows(obs))
        if self.communication is not None:
            self._com.record()
        return action.view(-1, self.n_agents)

    def decide(self, td: TensorDict) -> tuple[torch.Tensor, TensorDict | None]:
        """Steps 1-4 on an env step ``[B]``: ``(actions [B, n], transitions of agent rows)``."""
        rows = self._rows(td)
        if self._in_order:  # observe as before, then choose in agent order
            # (values after the pops: the codes the choices see may differ from ``rows``')
            ctx = self.context(rows, values=False)
            batch = self.executor.observe(rows, ctx, transitions=self.transitions)
            action, ctx = choose_in_order(self, rows, self._fixed_levels, ctx, batch)
            self.batch = batch if batch is None else with_values(batch, ctx)
        else:
            action, batch = super().decide(rows)
        if self.communication is not None:
            self._com.record()
        return action.view(-1, self.n_agents), batch

    def _rows(self, td: TensorDict) -> TensorDict:
        """The step as agent rows, with the others' ``U_l`` codes of every cooperation level."""
        rows = agent_rows(td)
        for level in self.levels:
            rows.set(level.key, self._others_code(level))
        return rows

    @property
    def messages(self) -> TensorDict:
        """This step's messages ``[B, n]`` (communication only).

        ``asked``: the agent communicated (its Ask to every other agent); ``told`` ``[B, n,
        n - 1]``: the other agents' Tell replies, their ``U_l`` tasks (-1 where nothing was
        asked).
        """
        return self._com.messages

    @property
    def communications(self) -> torch.Tensor:
        """Communications of every agent row since the agent was made ``[B * n]``."""
        return self._com.count

    @property
    def communication_cost(self) -> torch.Tensor:
        """ComCost paid by every agent row since the agent was made ``[B * n]``."""
        return self._com.count * self.communication.cost

    # ------------------------------------------------------------------ cooperation
    def own_codes(self, level: _Level) -> torch.Tensor:
        """Each agent row's current ``U_l`` subtask (``level.none`` without one) ``[B * n]``."""
        child = self.executor.stack.inst[:, level.depth + 1]  # the cooperative node's child
        return torch.take(level.code_of_inst_1, child + 1)  # (-1, no child: ``none``)

    def _others_code(self, level: _Level) -> torch.Tensor:
        """``sum_k code_k radix^rank(k)`` over the other agents of each agent row ``[B * n]``."""
        n = self.n_agents
        if n == 1:
            return torch.zeros_like(self.executor.learner)
        own = self.own_codes(level).view(-1, n)  # [B, n]
        communicating = self.communication is not None and level is self._com.level
        if communicating:
            own = self._com.late(own)
        others = own[:, self.other_agents.view(-1)].view(-1, n, n - 1)  # [B, n, n - 1]
        if communicating:
            others = self._com.replies = self._com.lose(others, self.policy.rng)
        return (others * level.weights).sum(-1).view(-1)

    def _end_communication(self, popped: torch.Tensor, ended_own: torch.Tensor) -> torch.Tensor:
        """A communication subtask lasts one ``U_l`` decision: cut it when its child ended.

        Its child's completion still learns (the child ended on its own; the target reads the
        communication subtask's value at ``s'``, as if it went on), while the parent's
        completion of ``Com`` / ``NotCom`` does not (cut, as any aborted child): the parent
        compares ``V(Com, s)`` with ``V(NotCom, s)``, the values of going on communicating or
        not. Ending them by their own termination instead made the ``U_1`` choice myopic
        (a completion that ends with the subtask sees no reward after its child).
        """
        d = self._com.depth
        cut = torch.zeros_like(popped)
        cut[:, d] = popped[:, d + 1] & ended_own[:, : d + 2].any(1)
        return cut

    # ------------------------------------------------------------------ schemes
    def _interrupt(self, popped: torch.Tensor, ended_own: torch.Tensor) -> torch.Tensor:
        """tau_any: the levels above the cooperation level of the agents to interrupt."""
        n, d = self.n_agents, self.levels[0].depth
        child = d + 1
        ended = popped[:, child] & ended_own[:, : child + 1].any(1)  # its U_l subtask ended
        others_ended = ended.view(-1, n).any(1).repeat_interleave(n) & ~ended
        self._pending = self._pending | others_ended
        acting = self.executor.acting
        now = self._pending & (acting if acting is not None else torch.ones_like(ended))
        self._pending = self._pending & ~now
        cut = torch.zeros_like(popped)
        cut[:, child] = now
        return cut


def _table_sets_of_rows(
    rng: BatchRNG,
    envs_per_learner: int,
    n: int,
    learner: Learner,
    shared_tables: bool,
    first_table: int | None,
) -> torch.Tensor:
    """The learner's table set ``p * n + j`` of each agent row of ``rng`` (module docstring).

    A clear error when the learner has too few sets (or, with ``first_table`` unset, not
    exactly the sets needed).
    """
    b = rng.batch_size
    if b % n:
        raise ValueError(f"{b} agent rows are not a multiple of {n} agents")
    row = torch.arange(b)  # (on the CPU: the executor reads it, then moves it)
    seed = row // (envs_per_learner * n)
    first = first_table or 0
    rows = first + (seed if shared_tables else seed * n + row % n)
    expected = (b // (envs_per_learner * n)) * (1 if shared_tables else n)
    if first_table is None and learner.n_learners != expected:
        raise ValueError(f"the learner has {learner.n_learners} table sets, {expected} needed")
    if learner.n_learners < first + expected:
        raise ValueError(f"the learner has no table sets {first}..{first + expected - 1}")
    return rows


class _WaitPolicy:
    """tau_all: at the cooperation level, an agent waits while another runs a ``U_1`` task.

    Wraps the agent's policy: the choice of an agent row at the first cooperation level is
    ``Cooperation.wait`` while any other agent of its env row runs a ``U_1`` subtask other than
    ``wait``; otherwise the wrapped policy chooses.
    """

    def __init__(self, agent: MultiAgentAgent, policy) -> None:
        self.agent, self.policy = agent, policy
        level = agent.levels[0]
        self.level = level
        self.wait_code = level.members.index(agent.cooperation.wait)
        self.rng = policy.rng

    def new_step(self) -> None:
        """Draw the wrapped policy's numbers."""
        self.policy.new_step()

    def select(self, inst, ctx: StepContext, available, step: int, push: int) -> Choice:
        """The wrapped policy's choice, or ``wait`` for the agents that must wait."""
        choice = as_choice(self.policy.select(inst, ctx, available, step, push))
        if push != self.level.depth:
            return choice
        n = self.agent.n_agents
        # after this step's pops, before its choices (agents choosing in order see fresh ones)
        code = self.agent.epoch_codes[0] if self.agent._in_order else None
        if code is None:
            code = self.agent.own_codes(self.level).view(-1, n)
        busy = (code != self.level.none) & (code != self.wait_code)
        others_busy = (busy.sum(1, keepdim=True) - busy.long() > 0).view(-1)
        node = self.agent.graph.inst_node[inst]
        slot = _child_slot(self.agent.graph, node, self.agent.cooperation.wait)
        wait = others_busy & (slot >= 0)
        choice.child = torch.where(wait, slot, choice.child)
        choice.greedy = choice.greedy | wait
        return choice


def _child_slot(graph: TaskGraph, node: torch.Tensor, name: str) -> torch.Tensor:
    """The slot of child ``name`` among the children of ``node [B]`` (-1 where it is none)."""
    target = graph.index[name]
    slots = graph.node_children[node]  # [B, A]
    hit = slots == target
    return torch.where(hit.any(-1), hit.long().argmax(-1), -1)


def agent_rng(seeds: Sequence[int], envs_per_learner: int, n_agents: int, stream: str):
    """Random numbers of the ``P * E * n`` agent rows (each agent its own stream)."""
    return BatchRNG(seeds, envs_per_learner * n_agents, stream)


@dataclass(frozen=True)
class MultiAgentConfig:
    """How the agents of a multi-agent env learn and decide (``MultiAgentAgent``).

    Attributes:
        cooperation: the cooperative subtasks (``None``: selfish agents).
        scheme: termination scheme at the first cooperation level.
        shared_tables: the agents of a seed share one table set.
        communication: COM-Cooperative HRL's communication level (``None``: none).
    """

    cooperation: Cooperation | None = None
    scheme: Scheme = "continue"
    shared_tables: bool = False
    communication: Communication | None = None

    def table_sets(self, n_seeds: int, n_agents: int) -> int:
        """Table sets a learner needs for ``n_seeds`` seeds of ``n_agents`` agents."""
        return n_seeds * (1 if self.shared_tables else n_agents)
