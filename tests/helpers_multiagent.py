"""Two toy ``MultiAgentBatchedEnv`` domains for the PettingZoo and TorchRL adapter tests.

- ``AsyncToyEnv``: event-driven, continuing-until-a-deadline. Action ``a`` of an agent takes
  ``a + 1`` time units; a step advances the row's clock to the end of the earliest running
  action, so only the agents whose actions ended act at the next epoch. Completing action ``a``
  earns the team ``a + 1`` (plus ``bonus`` when ``a`` is the row's random ``target``). The
  episode terminates when the clock reaches ``horizon``.
- ``SyncToyEnv``: discrete time, every agent acts at every step. Agents walk on a line of
  ``length`` cells (0 left, 1 stay, 2 right) from random cells; the team pays 1 per step and
  earns ``10`` when every agent stands on the same cell, which terminates the episode.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv


class AsyncToyEnv(MultiAgentBatchedEnv):
    """Agents start jobs of ``a + 1`` time units; the row jumps to the next job end.

    Shared fields: ``clock`` (declared), ``target`` (declared) and ``completed`` (jobs that
    ended at this step: an undeclared per-step metric). Agent fields: ``last_action``
    (declared) and ``remaining`` (float time left on the agent's running job, undeclared: a
    ``Box`` in PettingZoo, ``Unbounded`` in TorchRL).
    """

    state_keys = ("clock", "target", "completed", "remaining", "last_action")

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        n_agents: int = 3,
        n_actions: int = 3,
        horizon: int = 6,
        bonus: float = 10.0,
        max_episode_steps: int | None = None,
    ) -> None:
        super().__init__(seeds, envs_per_learner, n_agents, n_actions, max_episode_steps)
        self.horizon, self.bonus = horizon, bonus
        # the clock overshoots the horizon by at most the longest job minus one
        self.observation_sizes = {"clock": horizon + n_actions, "target": n_actions}
        self.agent_observation_sizes = {"last_action": n_actions}
        b, n = self.batch_size, n_agents
        self.clock = torch.zeros(b, dtype=torch.long)
        self.target = torch.zeros(b, dtype=torch.long)
        self.completed = torch.zeros(b, dtype=torch.long)
        self.remaining = torch.zeros(b, n, dtype=torch.long)
        self.last_action = torch.zeros(b, n, dtype=torch.long)

    def _reset_rows(self, mask):
        target = self.rng.integers(self.n_actions)
        m2 = mask[:, None]
        self.target = torch.where(mask, target, self.target)
        self.clock = torch.where(mask, 0, self.clock)
        self.completed = torch.where(mask, 0, self.completed)
        self.remaining = torch.where(m2, 0, self.remaining)
        self.last_action = torch.where(m2, 0, self.last_action)

    def _step_all(self, action, acting):
        self.remaining = torch.where(acting, action + 1, self.remaining)
        self.last_action = torch.where(acting, action, self.last_action)
        dt = self.remaining.min(dim=1).values
        self.remaining = self.remaining - dt[:, None]
        ended = self.remaining == 0
        value = (self.last_action + 1).float()
        value = value + self.bonus * (self.last_action == self.target[:, None]).float()
        reward = (value * ended).sum(1)
        self.completed = ended.sum(1)
        self.clock = self.clock + dt
        return reward, dt.float(), self.clock >= self.horizon, ended

    def _observe(self):
        return {
            "clock": self.clock.clone(),
            "target": self.target.clone(),
            "completed": self.completed.clone(),
        }

    def _observe_agents(self):
        return {"last_action": self.last_action.clone(), "remaining": self.remaining.float()}


class SyncToyEnv(MultiAgentBatchedEnv):
    """Agents meet on a line: -1 per step, +10 and the end of the episode when all meet.

    Shared field: ``spread`` (max minus min position, declared). Agent field: ``position``
    (declared).
    """

    state_keys = ("position",)

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        n_agents: int = 2,
        length: int = 5,
        max_episode_steps: int | None = 20,
    ) -> None:
        super().__init__(seeds, envs_per_learner, n_agents, 3, max_episode_steps)
        self.length = length
        self.observation_sizes = {"spread": length}
        self.agent_observation_sizes = {"position": length}
        self.position = torch.zeros(self.batch_size, n_agents, dtype=torch.long)

    def _reset_rows(self, mask):
        start = self.rng.integers(self.length, extra=self.n_agents)
        self.position = torch.where(mask[:, None], start, self.position)

    def _step_all(self, action, acting):
        self.position = (self.position + action - 1).clamp(0, self.length - 1)
        met = (self.position == self.position[:, :1]).all(1)
        reward = torch.where(met, 10.0, -1.0)
        return reward, torch.ones_like(reward), met, torch.ones_like(acting)

    def _observe(self):
        spread = self.position.max(1).values - self.position.min(1).values
        return {"spread": spread}

    def _observe_agents(self):
        return {"position": self.position.clone()}
