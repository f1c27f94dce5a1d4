"""Dispatching rules for the four-AGV task (Figure 6.7).

First come first serve, highest queue first and nearest station first, each choosing one job
per idle AGV at every decision.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from envs.four_agv import (
    BAYS,
    CAPACITY,
    DROP_OFF,
    EMPTY,
    IDLE,
    LOAD,
    N_STATIONS,
    PICK_UP,
    UNLOAD,
    WAREHOUSE_DROP,
    shortest_paths,
)
from hrl_torch.common.ops import one_hot_mask

#: the jobs a dispatcher (and the root) chooses among: DM_1..4, DA_1..4
N_JOBS = 2 * N_STATIONS

NO_JOB = -1


class DispatchRule:
    """A centralised AGV dispatcher: one rule policy for every agent row of a batch.

    A *job* is one of ``DM_1..4`` (fetch part ``i`` at ``Wi``, unload it at ``Di``) or
    ``DA_1..4`` (fetch an assembly at ``Pi``, unload it at ``WA``). Each call:

    1. forgets the jobs of rows that were reset, of agents that now carry something (the fetch
       is done: the load decides where to go) and of jobs with nothing left to fetch;
    2. gives every *free* acting agent (empty, no job), in agent order, the best open job by the
       rule's keys (``keys``). A job is open while it has unclaimed items (``DM_i``: the part
       in ``Wi``; ``DA_i``: the assemblies in ``Pi``) and, for ``DM_i``, room left in ``Di``
       after the parts on AGVs and the claimed ones: a claimed slot stays reserved, so a
       fetched part can always be unloaded and no two AGVs race for one item;
    3. drives every agent by the shortest path: an empty AGV with a job to the job's load
       location and ``Load``; a loaded one to ``Di`` (part ``i``) or ``WA`` (assembly) and
       ``Unload`` (``Idle`` while ``Di`` is full); an empty AGV without a job waits (``Idle``).

    The only memory is ``job`` ``[B, n]`` (``NO_JOB`` or the job an empty AGV is fetching).
    Every action is one that applies (a real move, a load that finds its item, an unload that
    has room) or ``Idle``.

    Args:
        batch_size: env rows ``B``.
        n_agents: agents per row ``n``; calls take ``B * n`` agent rows.
        capacity: the env's buffer capacity.
        device: where the memory lives.
    """

    name = "dispatch"

    def __init__(
        self,
        batch_size: int,
        n_agents: int,
        capacity: int = CAPACITY,
        device: torch.device | str = "cpu",
    ) -> None:
        self.device = torch.device(device)
        self.capacity = int(capacity)
        self.job = torch.full((batch_size, n_agents), NO_JOB, dtype=torch.long, device=self.device)
        dist, first = shortest_paths()
        self.dist, self.first = dist.to(self.device), first.to(self.device)
        as_long = dict(dtype=torch.long, device=self.device)
        self.load_at = torch.tensor([*BAYS, *PICK_UP], **as_long)  # [8]
        # where a loaded AGV goes, by status: part i to Di, any assembly to WA
        self.deliver_at = torch.tensor(
            [WAREHOUSE_DROP, *DROP_OFF, *([WAREHOUSE_DROP] * N_STATIONS)], **as_long
        )

    def reset(self) -> None:
        """Forget every job."""
        self.job.fill_(NO_JOB)

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The per-agent memory."""
        return {"job": self.job.clone()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore ``state_dict``."""
        self.job = state["job"].to(self.device).clone()

    def keys(
        self, queue: torch.Tensor, age: torch.Tensor, distance: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The rule: ``(primary, tie-break)`` keys ``[B, 8]`` of the jobs, highest wins.

        Args:
            queue: unclaimed items waiting at each job's load location ``[B, 8]``.
            age: how long the oldest unclaimed item has waited ``[B, 8]`` (s).
            distance: moves from the agent to each job's load location ``[B, 8]``.
        """
        raise NotImplementedError

    def __call__(self, td: TensorDict) -> torch.Tensor:
        """Primitive actions ``[B * n]`` for the agent rows ``td`` (``FourAGVEnv.agent_rows``)."""
        b, n = self.job.shape
        cap = self.capacity

        def per_agent(key: str) -> torch.Tensor:
            return td[key].view(b, n)

        def shared(key: str) -> torch.Tensor:
            value = td[key]
            return value.view(b, n, *value.shape[1:])[:, 0]

        loc, status, acting = per_agent("location"), per_agent("status"), per_agent("acting")
        drop = torch.stack([shared(f"drop_off_{k}") for k in range(1, N_STATIONS + 1)], -1)
        pick = torch.stack([shared(f"pick_up_{k}") for k in range(1, N_STATIONS + 1)], -1)
        bays = torch.stack([shared(f"warehouse_{k}") for k in range(1, N_STATIONS + 1)], -1)
        waiting = torch.cat([bays, pick], -1)  # [B, 8] items at the load locations
        pick_age = shared("pick_up_age")  # [B, 4, c]
        bay_age = shared("bay_age")  # [B, 4]

        # 1. forget finished, reset and stale jobs
        empty = status == EMPTY
        job = torch.where(shared("is_init")[:, None] | ~empty, NO_JOB, self.job)
        left_at_job = waiting.gather(1, job.clamp_min(0))
        job = torch.where((job >= 0) & (left_at_job == 0), NO_JOB, job)
        part_on_board = (status >= 1) & (status <= N_STATIONS)
        carried = (
            one_hot_mask(torch.where(part_on_board, status - 1, 0), N_STATIONS).long()
            * part_on_board[..., None]
        )
        reserved = drop + carried.sum(1)  # [B, 4] Di slots taken or promised to carried parts

        # 2. free acting agents take the best open job, one agent after the other
        for j in range(n):
            claims = (one_hot_mask(job + 1, N_JOBS + 1).long()[..., 1:]).sum(1)  # [B, 8]
            queue = waiting - claims
            room = cap - reserved - claims[:, :N_STATIONS]
            open_ = (queue > 0) & torch.cat([room > 0, torch.ones_like(room, dtype=torch.bool)], -1)
            next_item = claims[:, N_STATIONS:].clamp_max(cap - 1)[..., None]
            age = torch.cat([bay_age, pick_age.gather(2, next_item).squeeze(2)], -1)
            distance = self.dist[loc[:, j]][:, self.load_at]
            primary, second = self.keys(queue.float(), age, distance.float())
            best = lexicographic_argmax(open_, primary, second)
            free = acting[:, j] & empty[:, j] & (job[:, j] == NO_JOB)
            job[:, j] = torch.where(free, best, job[:, j])
        self.job = job

        # 3. drive: shortest path to the target, then load / unload (or wait)
        target = torch.where(empty, self.load_at[job.clamp_min(0)], self.deliver_at[status])
        room_at_drop = drop.gather(1, (status - 1).clamp(0, N_STATIONS - 1)) < cap
        here = torch.where(empty, LOAD, torch.where(part_on_board & ~room_at_drop, IDLE, UNLOAD))
        action = torch.where(loc == target, here, self.first[loc, target])
        action = torch.where(empty & (job == NO_JOB), IDLE, action)
        return action.reshape(-1)


def lexicographic_argmax(
    allowed: torch.Tensor, primary: torch.Tensor, second: torch.Tensor
) -> torch.Tensor:
    """``[B]``: the allowed column with the highest ``primary`` (ties: ``second``, then index).

    ``NO_JOB`` where nothing is allowed.
    """
    low = torch.finfo(primary.dtype).min
    primary = torch.where(allowed, primary, low)
    top = allowed & (primary == primary.max(-1, keepdim=True).values)
    best = torch.where(top, second, low).argmax(-1)
    return torch.where(allowed.any(-1), best, NO_JOB)


class FirstComeFirstServe(DispatchRule):
    """Serve the request that has waited longest (ties: the nearest, then the lowest job)."""

    name = "first come first serve"

    def keys(self, queue, age, distance):
        return age, -distance


class HighestQueueFirst(DispatchRule):
    """Serve the station with the most unclaimed items waiting (ties: the nearest).

    A bay's queue is its waiting part (0/1), a pick-up station's its assemblies (0..c): full
    output buffers, which block their machines, go first.
    """

    name = "highest queue first"

    def keys(self, queue, age, distance):
        return queue, -distance


class NearestStationFirst(DispatchRule):
    """Serve the closest station with an open request (ties: the one that waited longest)."""

    name = "nearest station first"

    def keys(self, queue, age, distance):
        return -distance, age


DISPATCH_RULES = {
    "fcfs": FirstComeFirstServe,
    "hqf": HighestQueueFirst,
    "nsf": NearestStationFirst,
}
