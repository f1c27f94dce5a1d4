"""The exact gain of a multi-agent hierarchical policy (Chapter 6) on a finite joint model.

A state of the joint system is ``x = (s, stacks)``: the env's joint state ``s`` and every
agent's Task-Stack after it chose its primitive action (the instances on it; what the greedy
choices depend on). From ``x`` the agents take their primitives (the joint action ``a``), the
env moves to ``s'_k`` with probability ``p_k`` and pays ``r(s, a)``; the agents pop what ended
at ``s'_k`` and push again, which gives ``x'_k``. ``joint_chain`` explores the states reachable
from the start states by running the real ``MultiAgentAgent`` (executor, cooperative
abstractions, greedy choices of the learned tables) on batches of them, so the chain is the
policy the learners act with, not a re-implementation of it. ``chain_gain`` is its long-run
average reward per step from the start distribution (power iteration on the lazy chain
``(I + P) / 2``, which has the same limit and no periodicity).

Greedy choices break ties by the first child (``FirstGreedy``), so the policy is a function of
the joint state.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict

from hrl_torch.execution.stack import TaskStack
from hrl_torch.modules.exploration import masked_argmax


class FirstGreedy:
    """The best available child, ties to the first: a deterministic greedy policy."""

    def select(self, q, available, u, step, learner=None):
        """``(choice [B], greedy [B])``."""
        choice = masked_argmax(q, available)
        return choice, torch.ones_like(choice, dtype=torch.bool)


@dataclass
class JointChain:
    """A finite Markov chain of a joint hierarchical policy.

    Attributes:
        next_state: ``[X, K]`` the chain state after each env outcome ``k``.
        prob: ``[K]`` the outcome probabilities (the same in every state).
        reward: ``[X]`` the team's expected reward of the joint action taken in each state.
        start: ``[X]`` the start distribution.
        env_state: ``[X]`` the env's joint state of each chain state.
    """

    next_state: torch.Tensor
    prob: torch.Tensor
    reward: torch.Tensor
    start: torch.Tensor
    env_state: torch.Tensor


def joint_chain(
    make_agent: Callable[[int], object],
    next_state: torch.Tensor,
    prob: torch.Tensor,
    reward: torch.Tensor,
    joint_action: Callable[[torch.Tensor], torch.Tensor],
    observe: Callable[[torch.Tensor], TensorDict],
    start: torch.Tensor,
    max_states: int = 2_000_000,
) -> JointChain:
    """Every joint state reachable from ``start`` under the agents' greedy policy.

    Args:
        make_agent: ``make_agent(m)``: a non-learning ``MultiAgentAgent`` over ``m`` env rows
            (``FirstGreedy`` choices).
        next_state: the env model ``[S, A, K]``: joint state after joint action ``a``, outcome
            ``k``.
        prob: ``[K]`` outcome probabilities.
        reward: ``[S, A]`` the team's reward.
        joint_action: per-agent actions ``[m, n]`` -> joint action indices ``[m]``.
        observe: env states ``[m]`` -> the env's step output ``[m]`` in those states (shared
            and ``"agents"`` fields; the step fields are set here).
        start: ``[S]`` the env's start distribution.
        max_states: refuse to explore more chain states than this.
    """
    index: dict[tuple, int] = {}
    env_states, nexts, rewards = [], [], []
    s0 = start.nonzero().squeeze(1)
    agent = make_agent(len(s0))
    agent.start(_step(observe(s0), is_init=True))
    n = agent.n_agents
    frontier = _keys(index, env_states, s0, agent.executor.stack.inst)
    stacks = {x: agent.executor.stack.inst[k * n : (k + 1) * n] for k, x in enumerate(frontier)}
    n_out = prob.shape[0]
    while frontier:
        if len(index) > max_states:
            raise ValueError(f"more than {max_states} joint states: too large to analyse")
        ids = torch.tensor(frontier)
        s = torch.tensor([env_states[x] for x in frontier])
        inst = torch.cat([stacks[x] for x in frontier])  # [m * n, D]
        action = _primitive_actions(agent.graph, inst).view(len(frontier), -1)
        a = joint_action(action)
        rewards.append((ids, reward[s, a]))
        s_next = next_state[s, a].reshape(-1)  # [m * K]
        agent = make_agent(len(s_next))
        agent.executor.stack = _stack_of(
            agent.graph, agent.executor.stack, _repeat_rows(inst, agent.n_agents, n_out)
        )
        agent.decide(_step(observe(s_next), is_init=False))
        before = len(index)
        targets = _keys(index, env_states, s_next, agent.executor.stack.inst)
        for k, x in enumerate(targets):
            if x >= before:
                stacks[x] = agent.executor.stack.inst[k * n : (k + 1) * n]
        nexts.append((ids, torch.tensor(targets).view(len(frontier), n_out)))
        frontier = list(range(before, len(index)))
    return _assembled_chain(env_states, nexts, rewards, prob, start, s0)


def _assembled_chain(env_states: list, nexts: list, rewards: list, prob, start, s0) -> JointChain:
    """The chain's tensors from ``joint_chain``'s records.

    Per explored frontier, its chain states' ids with their next chain states ``[m, K]``
    (``nexts``) or rewards (``rewards``); the chain starts in the env states ``s0`` (the
    first ids) as ``start`` weighs them.
    """
    x = len(env_states)
    chain_next = torch.zeros(x, prob.shape[0], dtype=torch.long)
    chain_reward = torch.zeros(x, dtype=torch.float64)
    for ids, t in nexts:
        chain_next[ids] = t
    for ids, r in rewards:
        chain_reward[ids] = r.double()
    first = torch.zeros(x, dtype=torch.float64)
    first[: len(s0)] = start[s0].double() / start[s0].sum()
    return JointChain(chain_next, prob.double(), chain_reward, first, torch.tensor(env_states))


def chain_gain(chain: JointChain, tol: float = 1e-12, max_iter: int = 1_000_000) -> float:
    """Long-run average reward per step of ``chain`` from its start distribution."""
    d = chain.start.clone()
    src = torch.arange(len(d)).repeat_interleave(chain.prob.shape[0])
    dst = chain.next_state.reshape(-1)
    weight = chain.prob.repeat(len(d))
    for _ in range(max_iter):
        moved = torch.zeros_like(d).index_add_(0, dst, d[src] * weight)
        new = 0.5 * (d + moved)
        if float((new - d).abs().sum()) < tol:
            return float(new @ chain.reward)
        d = new
    raise RuntimeError(f"the chain's distribution did not settle in {max_iter} iterations")


def _step(obs: TensorDict, is_init: bool) -> TensorDict:
    """``obs`` as an env step output (no time limit, every agent acting)."""
    m = obs.batch_size[0]
    out = obs.clone(False)
    flag = torch.zeros(m, dtype=torch.bool)
    out.update(
        reward=torch.zeros(m),
        duration=torch.ones(m),
        terminated=flag,
        truncated=flag,
        is_init=flag | is_init,
    )
    agents = out["agents"]
    n = agents.batch_size[1]
    agents.update(
        acting=torch.ones(m, n, dtype=torch.bool),
        reward=torch.zeros(m, n),
        duration=torch.ones(m, n),
    )
    return out


def _primitive_actions(graph, inst: torch.Tensor) -> torch.Tensor:
    """The env action of the primitive on top of each stack ``inst [R, D]``."""
    top = inst.amax(1)  # instances are numbered breadth first: the deepest is on top
    return graph.node_action[graph.inst_node[top]]


def _repeat_rows(inst: torch.Tensor, n: int, k: int) -> torch.Tensor:
    """Agent rows ``[m * n, D]`` of ``m`` env rows, each env row repeated ``k`` times."""
    m = inst.shape[0] // n
    return inst.view(m, n, -1).repeat_interleave(k, 0).reshape(m * k * n, -1)


def _stack_of(graph, template: TaskStack, inst: torch.Tensor) -> TaskStack:
    """``template`` (empty stacks) holding the instances ``inst [R, D]``."""
    f = template.tensors()
    f["inst"] = inst.clone()
    f["node"] = graph.path_node_1.index_select(0, inst.amax(1) + 1)
    f["top"] = (inst >= 0).sum(1) - 1
    return TaskStack.from_tensors(f, inst.shape[0])


def _keys(index, env_states, s: torch.Tensor, inst: torch.Tensor) -> list[int]:
    """The chain index of every (env state, stacks); new ones are added."""
    rows = torch.cat([s[:, None], inst.view(len(s), -1)], 1).tolist()
    out = []
    for row in rows:
        key = tuple(row)
        if key not in index:
            index[key] = len(index)
            env_states.append(row[0])
        out.append(index[key])
    return out


def optimal_gain(
    next_state: torch.Tensor,
    prob: torch.Tensor,
    reward: torch.Tensor,
    tol: float = 1e-9,
    max_iter: int = 100_000,
) -> float:
    """The best gain of the flat joint MDP (any joint policy): relative value iteration.

    ``next_state [S, A, K]``, ``prob [K]``, ``reward [S, A]``; the lazy operator ``(h + T h)
    / 2`` (no periodicity). An upper bound for every hierarchical and every decentralized
    policy.
    """
    h = torch.zeros(next_state.shape[0], dtype=torch.float64)
    p, r = prob.double(), reward.double()
    for _ in range(max_iter):
        q = r + (h[next_state] * p).sum(-1)  # [S, A]
        t = 0.5 * (h + q.amax(1))
        gain = t[0] - h[0]
        new = t - t[0]
        if float((new - h).abs().max()) < tol:
            return 2.0 * float(gain)
        h = new
    raise RuntimeError(f"relative value iteration did not converge in {max_iter} iterations")
