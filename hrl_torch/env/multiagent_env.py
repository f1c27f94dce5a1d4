"""Batched multi-agent environments (Chapter 6): ``n`` agents per env row, decisions per agent.

A ``MultiAgentBatchedEnv`` steps ``B = P * E`` env rows, each with ``n_agents`` agents that
share the state of the row (the factory, the taxi grid) and a team reward. One ``step`` takes
every agent's primitive action ``[B, n]`` and advances every row to its next *decision epoch*:

- in discrete time (trash collection, two taxis) every agent acts at every step;
- in an event-driven continuous-time env (the four AGVs) a step advances the row's clock to the
  end of the earliest running action; only the agents whose actions ended act (``acting``), the
  others' actions keep running and their new actions are ignored. This is the tau_continue
  decision scheme of Section 6.1 at the level of primitive actions.

The output is a TensorDict ``[B]``:

- the row's shared observation fields (``_observe``), ``reward`` ``[B]`` (team reward of the
  step), ``duration`` ``[B]`` (time the step advanced), ``terminated`` / ``truncated`` /
  ``is_init`` ``[B]`` as in ``hrl_torch.env.batched`` (next-step auto-reset);
- ``"agents"``: a TensorDict ``[B, n]`` (TorchRL's multi-agent convention) with each agent's own
  observation fields (``_observe_agents``) and

  - ``acting`` ``[B, n]``: the agent's action ended at this step, so it chooses now (every agent
    of a row that was reset, terminated or truncated);
  - ``reward`` / ``duration`` ``[B, n]``: the reward and the time since the agent's action
    started, for acting agents (0 for the others): the reward and duration of the agent's own
    primitive step, as its SMDP sees it. The reward is the team's, or, when the env returns one
    reward per agent (``[B, n]``: each agent's own share, their sum the team's), the agent's
    own share.

``agent_rows`` flattens a step into ``B * n`` *agent rows* (row ``b * n + j`` is agent ``j`` of
env row ``b``), each looking like a single-agent step: the agent's fields, the shared fields,
its ``reward`` and ``duration``, the row's flags, ``acting`` and ``agent`` (its index).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict

from hrl_torch.common.devices import DeferredCheck
from hrl_torch.env.batched import BatchedEnv, on_env_device


class MultiAgentBatchedEnv(BatchedEnv):
    """Base class of torch-batched multi-agent domains (see the module docstring).

    Subclasses implement ``_reset_rows(mask [B])``, ``_step_all(action [B, n], acting [B, n])
    -> (reward [B] or [B, n], duration [B], terminated [B], next acting [B, n])`` (the team's
    reward, or each agent's own share of it), ``_observe()`` (the shared fields) and
    ``_observe_agents()`` (fields ``[B, n, ...]``), and list their state
    tensors in ``state_keys``. ``_step_all`` applies the actions of the agents that are
    ``acting`` and advances every row to its next decision epoch. Random numbers: draw the same
    amount for every row whatever its state (``self.rng``), so a learner's stream does not depend
    on its population.

    Args:
        seeds: one seed per learner.
        envs_per_learner: ``E``.
        n_agents: agents per env row.
        n_actions: size of each agent's discrete action space.
        max_episode_steps: time limit in steps (decision epochs), ``None`` for none.
        device: where the state lives.
    """

    #: per-agent discrete observation fields and their sizes (shape ``[B, n]``, long)
    agent_observation_sizes: dict[str, int] = {}

    def __init__(
        self,
        seeds: Sequence[int],
        envs_per_learner: int,
        n_agents: int,
        n_actions: int,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(seeds, envs_per_learner, n_actions, max_episode_steps, device)
        if n_agents < 1:
            raise ValueError(f"n_agents must be >= 1, got {n_agents}")
        self.n_agents = int(n_agents)
        shape = (self.batch_size, self.n_agents)
        self.acting = torch.ones(shape, dtype=torch.bool, device=self.device)
        self.pending_reward = torch.zeros(shape, device=self.device)
        self.pending_time = torch.zeros(shape, device=self.device)

    # -- subclass hooks
    def _step_all(self, action: torch.Tensor, acting: torch.Tensor):  # type: ignore[override]
        raise NotImplementedError

    def _observe_agents(self) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def agent_observation(self) -> dict[str, torch.Tensor]:
        """Every agent's own observation fields now, ``[B, n, ...]`` (``_observe_agents``)."""
        return self._observe_agents()

    def restart_rows(self, mask: torch.Tensor) -> TensorDict:
        """New episodes in the rows ``mask`` (all their agents act); the other rows unchanged.

        Returns every row's fields, ``mask`` as ``is_init`` (a partial ``reset``).
        """
        m2 = mask[:, None]
        self._reset_rows(mask)
        self.elapsed = torch.where(mask, 0, self.elapsed)
        self.done = self.done & ~mask
        self.acting = self.acting | m2
        self.pending_reward = torch.where(m2, 0.0, self.pending_reward)
        self.pending_time = torch.where(m2, 0.0, self.pending_time)
        zero = torch.zeros(self.batch_size, device=self.device)
        false = torch.zeros(self.batch_size, dtype=torch.bool, device=self.device)
        return self._output(zero, zero, false, false, mask, torch.zeros_like(self.pending_time))

    # -- public API
    def reset(self) -> TensorDict:
        """Start a new episode in every row; every agent acts."""
        every = torch.ones(self.batch_size, dtype=torch.bool, device=self.device)
        self._reset_rows(every)
        self.elapsed.zero_()
        self.done.zero_()
        self.acting.fill_(True)
        self.pending_reward.zero_()
        self.pending_time.zero_()
        zero = torch.zeros(self.batch_size, device=self.device)
        flag = torch.zeros(self.batch_size, dtype=torch.bool, device=self.device)
        return self._output(zero, zero, flag, flag, every, torch.zeros_like(self.pending_time))

    def step(self, action: torch.Tensor) -> TensorDict:
        """Apply the acting agents' actions ``[B, n]`` and advance to the next decision epoch."""
        action = self._check_action(torch.as_tensor(action, device=self.device))
        was_done = self.done.clone()
        reward, duration, terminated, next_acting = self._step_all(action, self.acting)
        on_env_device(self, "_step_all", reward=reward, duration=duration, terminated=terminated)
        self.elapsed += 1
        if self.max_episode_steps is None:
            truncated = torch.zeros_like(terminated)
        else:
            truncated = self.elapsed >= self.max_episode_steps
        self._reset_rows(was_done)
        self.elapsed = torch.where(was_done, 0, self.elapsed)
        zero = torch.zeros((), device=self.device)
        own = reward.float() if reward.dim() == 2 else None
        if own is not None:  # each agent's own share; the team's reward is their sum
            own = own.masked_fill(was_done[:, None], 0.0)
            reward = own.sum(1)
        reward = torch.where(was_done, zero, reward.float())
        duration = torch.where(was_done, zero, duration.float())
        terminated = terminated & ~was_done
        truncated = truncated & ~was_done
        self.done = terminated | truncated
        # every agent of a row that ends or restarts acts now (its running action is cut)
        acting = next_acting | (self.done | was_done)[:, None]
        self.pending_reward += reward[:, None] if own is None else own
        self.pending_time += duration[:, None]
        agent_reward = torch.where(acting, self.pending_reward, zero)
        agent_time = torch.where(acting, self.pending_time, zero)
        self.pending_reward = torch.where(acting, zero, self.pending_reward)
        self.pending_time = torch.where(acting, zero, self.pending_time)
        self.acting = acting
        return self._output(
            reward, duration, terminated, truncated, was_done, agent_time, agent_reward
        )

    def _check_action(self, action: torch.Tensor) -> torch.Tensor:
        """Actions ``[B, n]`` in range for every acting agent of a live row (others: zeroed)."""
        shape = (self.batch_size, self.n_agents)
        if action.shape != shape:
            raise ValueError(f"action must have shape {list(shape)}, got {tuple(action.shape)}")
        bad = (action < 0) | (action >= self.n_actions)
        live = self.acting & ~self.done[:, None]
        if self.deferred_action is not None:  # (no read: hrl_torch.training.deferred)
            live_bad = bad & live
            self.deferred_action.record(live_bad.any(1), action=action, agents=live_bad)
            return torch.where(bad, torch.zeros_like(action), action)
        if bool((bad & live).any()):
            row, agent = (int(v) for v in (bad & live).nonzero()[0])
            raise ValueError(
                f"action {int(action[row, agent])} of agent {agent} outside the action space "
                f"[0, {self.n_actions}) (env row {row})"
            )
        return torch.where(bad, torch.zeros_like(action), action)

    def defer_checks(self) -> DeferredCheck:
        """Check actions without a device read from now on (``hrl_torch.training.deferred``)."""
        n = self.n_actions

        def describe(row: int, saved: dict) -> Exception:
            agent = int(saved["agents"][row].nonzero()[0])
            action = int(saved["action"][row, agent])
            return ValueError(
                f"action {action} of agent {agent} outside the action space [0, {n}) "
                f"(env row {row})"
            )

        self.deferred_action = DeferredCheck(describe)
        return self.deferred_action

    def _output(
        self, reward, duration, terminated, truncated, is_init, agent_time, agent_reward=None
    ) -> TensorDict:
        fields = self._observe()
        on_env_device(self, "_observe", **fields)
        fields.update(
            reward=reward,
            duration=duration,
            terminated=terminated,
            truncated=truncated,
            is_init=is_init,
        )
        agents = self._observe_agents()
        agents.update(
            acting=self.acting.clone(),
            reward=torch.zeros_like(agent_time) if agent_reward is None else agent_reward,
            duration=agent_time,
        )
        b, n = self.batch_size, self.n_agents
        fields["agents"] = TensorDict(agents, batch_size=[b, n], device=self.device)
        return TensorDict(fields, batch_size=[b], device=self.device)

    def agent_rows(self, td: TensorDict) -> TensorDict:
        """One step as ``B * n`` agent rows (see the module docstring), batch ``[B * n]``."""
        return agent_rows(td)

    def learner_of_agent_row(self) -> torch.Tensor:
        """Learner (seed) of every agent row ``[B * n]``."""
        return self.learner_of_row().repeat_interleave(self.n_agents)

    def state_dict(self) -> dict:
        """Every tensor and counter needed to continue exactly."""
        state = super().state_dict()
        state.update(
            acting=self.acting.clone(),
            pending_reward=self.pending_reward.clone(),
            pending_time=self.pending_time.clone(),
        )
        return state

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict``; shapes must match this env."""
        super().load_state_dict(state)
        for k in ("acting", "pending_reward", "pending_time"):
            if state[k].shape != vars(self)[k].shape:
                raise ValueError(f"env state {k!r}: shape {tuple(state[k].shape)} mismatch")
            setattr(self, k, state[k].to(self.device).clone())


def agent_rows(td: TensorDict) -> TensorDict:
    """A multi-agent step ``[B]`` as ``B * n`` agent rows (row ``b * n + j``: agent ``j``).

    Each row holds the agent's own fields (``td["agents"]``: its ``reward``, ``duration`` and
    ``acting`` among them), the shared fields of its env row (the team's step ``reward`` and
    ``duration`` left out), and ``agent`` (its index). A shared field with the name of an
    agent field is an error (one would hide the other).
    """
    agents = td["agents"]
    b, n = agents.batch_size
    rows = {k: v.reshape(b * n, *v.shape[2:]) for k, v in agents.items()}
    for key, value in td.items():
        if key in ("agents", "reward", "duration"):
            continue
        if key in rows:
            raise ValueError(f"field {key!r} is both an agent field and a shared field")
        rows[key] = value.repeat_interleave(n, dim=0)
    rows["agent"] = torch.arange(n, device=agents.device).repeat(b)
    return TensorDict(rows, batch_size=[b * n], device=agents.device)
