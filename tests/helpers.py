"""Small finite envs and random hierarchies for executor and learner tests."""

from __future__ import annotations

import torch

from hrl_torch.env.batched import BatchedEnv
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask


class TableEnv(BatchedEnv):
    """A finite MDP given by tables: ``next_state [S, A]``, ``reward [S, A]``, ``terminal [S]``.

    Episodes start uniformly in ``starts`` and end on entering a terminal state.
    """

    state_keys = ("state",)

    def __init__(
        self,
        next_state,
        reward,
        terminal,
        starts,
        seeds=(0,),
        envs_per_learner=1,
        max_episode_steps=None,
    ):
        super().__init__(seeds, envs_per_learner, next_state.shape[1], max_episode_steps)
        self.next_state, self.reward_table = next_state, reward
        self.terminal, self.starts = terminal, starts
        self.observation_sizes = {"observation": next_state.shape[0]}
        self.state = torch.zeros(self.batch_size, dtype=torch.long)

    def _reset_rows(self, mask):
        fresh = self.starts[self.rng.integers(len(self.starts))]
        self.state = torch.where(mask, fresh, self.state)

    def _step_all(self, action):
        reward = self.reward_table[self.state, action]
        self.state = self.next_state[self.state, action]
        return reward, torch.ones_like(reward), self.terminal[self.state]

    def _observe(self):
        return {"observation": self.state}


def random_table_env(n_states, n_actions, seed, terminal_frac=0.1, **kw):
    g = torch.Generator().manual_seed(seed)
    next_state = torch.randint(0, n_states, (n_states, n_actions), generator=g)
    reward = torch.randint(-3, 3, (n_states, n_actions), generator=g).float()
    terminal = torch.rand(n_states, generator=g) < terminal_frac
    terminal[0] = False
    starts = (~terminal).nonzero().squeeze(1)
    return TableEnv(next_state, reward, terminal, starts, **kw)


def random_hierarchy(n_subtasks, n_states, n_actions, seed, term_frac=0.3, max_children=4):
    """A random DAG: subtask k calls subtasks > k and at least one primitive."""
    g = torch.Generator().manual_seed(seed)
    prim_names = [f"a{j}" for j in range(n_actions)]
    nodes = []
    for k in range(n_subtasks):
        later = [f"T{j}" for j in range(k + 1, n_subtasks)]
        pool = later + prim_names
        n_child = int(torch.randint(1, min(max_children, len(pool)) + 1, (1,), generator=g))
        picks = torch.randperm(len(pool), generator=g)[:n_child].tolist()
        children = [pool[j] for j in picks]
        if not any(c in prim_names for c in children):
            children.append(prim_names[int(torch.randint(0, n_actions, (1,), generator=g))])
        term = torch.rand(n_states, generator=g) < (0.0 if k == 0 else term_frac)
        n_abs = int(torch.randint(1, n_states + 1, (1,), generator=g))
        nodes.append(
            Subtask(
                f"T{k}",
                children,
                n_states=n_abs,
                abstract=lambda o, m=n_abs: o["observation"] % m,
                terminated=lambda o, t=term: t[o["observation"]],
            )
        )
    nodes += [Primitive(n, j) for j, n in enumerate(prim_names)]
    return TaskGraph("T0", nodes, n_actions=n_actions)
