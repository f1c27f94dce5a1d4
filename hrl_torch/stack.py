"""The Task-Stack (Section 3.2) of every env row, as one typed batch of tensors.

A Task-Stack holds, per level, the subtask instance running there and what the executor needs
to close the SMDP transition of the child that level chose: the child, the abstract state
where the child started, and the reward and time accumulated since. ``HierarchicalExecutor``
keeps one ``TaskStack`` for its ``B`` rows, pushes and pops it, and checkpoints it through
``state_dict``; ``describe`` prints one row's stack by name.
"""

from __future__ import annotations

import torch
from tensordict import tensorclass

from hrl_torch.graph import TaskGraph


@tensorclass
class TaskStack:
    """Task-Stacks of ``B`` rows, ``batch_size [B]``, ``W = levels + 1`` columns.

    Column ``W - 1`` is a *trash* level: masked pushes write there, so a push is one
    ``scatter_`` per field with no gather or ``where``. Level ``0`` holds the root.

    Per level ``[B, W]`` (accumulators count from the start of the level's current child):

    - ``inst``: instance at each level (-1: empty); ``child``: the child slot it chose;
    - ``start_state``: abstract state of the level's node where the child started;
    - ``steps`` (primitive steps ``N``), ``time`` (duration ``tau``), ``reward`` (external
      reward), ``disc_reward`` (``sum gamma^t r``), ``internal`` (discounted shaping reward);
    - ``greedy`` (the child and every ancestor's choice were greedy), ``own_greedy``;
    - ``inv_steps``: primitive steps of the level's own invocation (the guard);
    - ``vis_state``, ``vis_steps``, ``vis_time`` ``[B, W, L]``: the last ``L`` states visited
      during the child (all-states updating);
    - ``start_features`` ``[B, W, F]``: the node's features where the child started.

    Per row: ``top [B]`` (level on top, -1: empty), ``done [B]`` (the episode ended at the last
    step; the row waits for its reset), ``cont_action [B, A]`` (the action vector of the
    continuous primitive on top), ``memory [B, n_nodes, M]`` (what the running invocation of
    each node remembered when it started).
    """

    inst: torch.Tensor
    child: torch.Tensor
    start_state: torch.Tensor
    steps: torch.Tensor
    time: torch.Tensor
    reward: torch.Tensor
    disc_reward: torch.Tensor
    internal: torch.Tensor
    greedy: torch.Tensor
    own_greedy: torch.Tensor
    inv_steps: torch.Tensor
    vis_state: torch.Tensor
    vis_steps: torch.Tensor
    vis_time: torch.Tensor
    start_features: torch.Tensor
    top: torch.Tensor
    done: torch.Tensor
    cont_action: torch.Tensor
    memory: torch.Tensor

    @classmethod
    def empty(cls, graph: TaskGraph, batch: int, visits: int = 1) -> TaskStack:
        """Empty stacks for ``batch`` rows of ``graph`` keeping ``visits`` visited states."""
        dev = graph.node_children.device
        b, w = batch, graph.max_levels + 1

        def zeros(*shape, dtype=torch.float32):
            return torch.zeros(b, *shape, dtype=dtype, device=dev)

        long, flag = torch.long, torch.bool
        return cls(
            inst=torch.full((b, w), -1, dtype=long, device=dev),
            child=zeros(w, dtype=long),
            start_state=zeros(w, dtype=long),
            steps=zeros(w, dtype=long),
            time=zeros(w),
            reward=zeros(w),
            disc_reward=zeros(w),
            internal=zeros(w),
            greedy=torch.ones(b, w, dtype=flag, device=dev),
            own_greedy=torch.ones(b, w, dtype=flag, device=dev),
            inv_steps=zeros(w, dtype=long),
            vis_state=zeros(w, visits, dtype=long),
            vis_steps=zeros(w, visits, dtype=long),
            vis_time=zeros(w, visits),
            start_features=zeros(w, max(graph.max_features, 1)),
            top=torch.full((b,), -1, dtype=long, device=dev),
            done=zeros(dtype=flag),
            cont_action=zeros(max(graph.action_dim, 1)),
            memory=zeros(graph.n_nodes, max(graph.max_memory, 1)),
            batch_size=[b],
        )

    def clear(self) -> None:
        """Empty every stack (every row starts at the root on the next push)."""
        self.top.fill_(-1)
        self.inst.fill_(-1)
        self.done.zero_()

    def describe(self, graph: TaskGraph, row: int) -> str:
        """Row ``row``'s stack from the root to the top, e.g. ``Root/Get/Navigate_R/North``."""
        top = int(self.top[row])
        if top < 0:
            return "(empty)"
        return graph.instance_path(int(self.inst[row, top]))

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Every field (cloned), for exact resume."""
        return {k: v.clone() for k, v in self.to_dict().items()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore ``state_dict`` of stacks of the same shape (nothing changes on a mismatch)."""
        mine = self.to_dict()
        if set(state) != set(mine):
            raise ValueError(f"Task-Stack fields {sorted(state)} != {sorted(mine)}")
        for k, v in state.items():
            if v.shape != mine[k].shape:
                raise ValueError(
                    f"Task-Stack field {k!r} has shape {tuple(v.shape)}, "
                    f"expected {tuple(mine[k].shape)}"
                )
        for k, v in state.items():
            setattr(self, k, v.to(mine[k].device).clone())
