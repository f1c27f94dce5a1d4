"""Helpers shared by the small gridworlds (``envs.four_rooms``, ``envs.key_door``).

``TableEnv`` is a deterministic finite env stepped by lookups in its transition tables.

A layout is a tuple of equal-length strings; ``#`` is a wall, every other character a free
cell. Free cells are numbered row-major. Moves are 0 north, 1 south, 2 east, 3 west; a move
into a wall or off the map leaves the agent where it is.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict

from hrl_torch.env.batched import BatchedEnv

NORTH, SOUTH, EAST, WEST = range(4)
MOVES = ((-1, 0), (1, 0), (0, 1), (0, -1))


def free_cells(layout: tuple[str, ...]) -> tuple[tuple[int, int], ...]:
    """``(row, col)`` of every free cell, row-major (the cell index is the position here)."""
    return tuple((r, c) for r, line in enumerate(layout) for c, ch in enumerate(line) if ch != "#")


def move_table(layout: tuple[str, ...]) -> torch.Tensor:
    """``[n_cells, 4]``: the cell each move leads to (the same cell into a wall)."""
    cells = free_cells(layout)
    index = {rc: k for k, rc in enumerate(cells)}
    table = torch.zeros(len(cells), 4, dtype=torch.long)
    for k, (r, c) in enumerate(cells):
        for a, (dr, dc) in enumerate(MOVES):
            table[k, a] = index.get((r + dr, c + dc), k)
    return table


def optimal_values(
    next_state: torch.Tensor, reward: torch.Tensor, terminated: torch.Tensor
) -> torch.Tensor:
    """``[S]``: the optimal undiscounted return from every state of a deterministic model.

    Value iteration on ``next_state``, ``reward``, ``terminated`` ``[S, A]`` tables until no
    value changes (every state must reach a termination; returns are finite).
    """
    value = torch.zeros(next_state.shape[0], dtype=torch.float64)
    reward, done = reward.double(), terminated
    for _ in range(10 * next_state.shape[0]):
        q = reward + torch.where(done, 0.0, value[next_state])
        new = q.amax(1)
        if torch.equal(new, value):
            return value
        value = new
    raise RuntimeError("value iteration did not converge (a state that never terminates?)")


class TableEnv(BatchedEnv):
    """A deterministic finite env given by its tables (taxi, four rooms, key and door).

    A subclass sets ``observation_sizes``, ``transition_tables`` (``() -> (next_state,
    reward, terminated)`` ``[S, A]`` and the start states ``[K]``; a reset draws one
    uniformly), ``decode`` (``state [B] -> observation fields``) and ``time_limit``.

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``; the batch is ``len(seeds) * E``.
        max_episode_steps: time limit (-1, the default: the class's ``time_limit``).
        device: where the state lives.
    """

    state_keys = ("state",)
    subset_safe = True  # the row's state is ``state`` alone
    time_limit: int | None = None
    transition_tables = None  # set by subclasses (a staticmethod)
    decode = None  # set by subclasses (a staticmethod)

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        max_episode_steps: int | None = -1,
        device: torch.device | str = "cpu",
    ) -> None:
        next_state, reward, terminated, starts = self.transition_tables()
        limit = self.time_limit if max_episode_steps == -1 else max_episode_steps
        super().__init__(seeds, envs_per_learner, next_state.shape[1], limit, device)
        self.next_state = next_state.to(self.device)
        self.reward_table = reward.to(self.device)
        self.terminal_table = terminated.to(self.device)
        self.starts = starts.to(self.device)
        self.state = torch.zeros(self.batch_size, dtype=torch.long, device=self.device)
        # flat views of the tables, and the observation fields of every state, one row per
        # field (of one dtype: taken by one lookup per step)
        self._flat = {"reward": reward, "terminated": terminated, "next": next_state}
        self._flat = {k: v.reshape(-1).to(self.device) for k, v in self._flat.items()}
        fields = self.decode(torch.arange(next_state.shape[0]))
        self._field_names = list(fields)
        self._field_table = None
        if len({v.dtype for v in fields.values()}) == 1:
            self._field_table = torch.stack([fields[k] for k in self._field_names])
            self._field_table = self._field_table.to(self.device)

    @classmethod
    def tabulate(cls, graph):
        """``graph`` with its context computed once for every state (a lookup per step).

        For graphs whose predicates read the state alone, as this env's ``decode`` gives it.
        """
        states = torch.arange(cls.transition_tables()[0].shape[0])
        graph.tabulate(TensorDict(cls.decode(states), batch_size=[states.shape[0]]))
        return graph

    @classmethod
    def gymnasium(cls, render_mode: str | None = None):
        """One row of this env as a ``gymnasium.Env`` (``hrl_torch.env.adapters``)."""
        from hrl_torch.env.adapters import BatchedToGymnasium

        return BatchedToGymnasium(lambda seeds, n: cls(seeds, n), render_mode=render_mode)

    def _observe(self) -> dict[str, torch.Tensor]:
        if self._field_table is None:
            return self.decode(self.state)
        rows = self._field_table.index_select(1, self.state).unbind(0)
        return dict(zip(self._field_names, rows, strict=True))

    def _reset_rows(self, mask: torch.Tensor) -> None:
        fresh = self.starts.index_select(0, self.rng.integers(len(self.starts)))  # every row
        self.state = torch.where(mask, fresh, self.state)

    def _step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        flat = self.state * self.n_actions + action  # index_select on flat tables: fast on CPU
        reward = self._flat["reward"].index_select(0, flat)
        terminated = self._flat["terminated"].index_select(0, flat)
        self.state = self._flat["next"].index_select(0, flat)
        return reward, self._unit_durations(), terminated

    def _unit_durations(self) -> torch.Tensor:
        """Ones ``[B]``: every step takes one time unit (kept)."""
        ones = self.__dict__.get("_ones")
        if ones is None or ones.shape[0] != self.batch_size or ones.device != self.device:
            ones = self._ones = torch.ones(self.batch_size, device=self.device)
        return ones
