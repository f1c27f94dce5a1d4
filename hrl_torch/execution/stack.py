"""The Task-Stack (Section 3.2) of every env row, as one typed batch of tensors.

A Task-Stack holds, per level, the subtask instance running there and what the executor needs
to close the SMDP transition of the child that level chose: the child, the abstract state
where the child started, and the reward and time accumulated since. ``HierarchicalExecutor``
keeps one ``TaskStack`` for its ``B`` rows and replaces it by a new one at every pop and push
(it never writes into a stack in place), so a stack can travel in a rollout TensorDict the way
a recurrent policy's hidden state does (``hrl_torch.training.collector``), and an old stack stays
valid after the executor moved on. ``describe`` prints one row's stack by name.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, tensorclass

from hrl_torch.hierarchy.graph import TaskGraph


@tensorclass
class TaskStack:
    """Task-Stacks of ``B`` rows, ``batch_size [B]``, ``D`` levels (level ``0``: the root).

    Per level ``[B, D]`` (accumulators count from the start of the level's current child):

    - ``inst``: instance at each level (-1: empty), ``node`` its node (the root's where
      empty); ``child``: the child slot it chose (0 at and above the top);
    - ``start_state``: abstract state of the level's node where the child started (for the
      primitive on top: the primitive's own abstract state);
    - ``steps`` (primitive steps ``N``), ``time`` (duration ``tau``), ``reward`` (external
      reward), ``disc_reward`` (``sum gamma^t r``), ``internal`` (discounted shaping reward);
    - ``greedy`` (the child and every ancestor's choice were greedy), ``own_greedy`` (True
      at and above the top);
    - ``inv_steps``: primitive steps of the level's own invocation (the guard);
    - ``vis_state``, ``vis_steps``, ``vis_time``, ``vis_internal`` ``[B, D, L]``: the last
      ``L`` states visited during the child, with the steps, time and discounted shaping reward
      accumulated up to each (all-states updating);
    - ``start_features`` ``[B, D, F]``: the node's features where the child started;
    - ``score_index``, ``score_value`` ``[B, D, K]``: the likelihood-ratio term of the child's
      choice, as a sparse increment into a policy-gradient learner's parameters (PG nodes).

    Per row: ``top [B]`` (level on top, -1: empty), ``done [B]`` (the episode ended at the last
    step; the row waits for its reset), ``cont_action [B, A]`` (the action vector of the
    continuous primitive on top), ``memory [B, n_nodes, M]`` (what the running invocation of
    each node remembered when it started).
    """

    inst: torch.Tensor
    node: torch.Tensor
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
    vis_internal: torch.Tensor
    start_features: torch.Tensor
    score_index: torch.Tensor
    score_value: torch.Tensor
    top: torch.Tensor
    done: torch.Tensor
    cont_action: torch.Tensor
    memory: torch.Tensor

    @classmethod
    def empty(
        cls, graph: TaskGraph, batch: int, visits: int = 1, score_width: int = 0
    ) -> TaskStack:
        """Empty stacks for ``batch`` rows of ``graph``.

        Args:
            graph: the task graph (its device is the stacks').
            batch: rows ``B``.
            visits: visited states kept per level (all-states updating).
            score_width: nonzeros of one choice's likelihood-ratio term (PG learners; 0: none).
        """
        dev = graph.node_children.device
        b, d = batch, graph.max_levels

        def zeros(*shape, dtype=torch.float32):
            return torch.zeros(b, *shape, dtype=dtype, device=dev)

        long, flag = torch.long, torch.bool
        k = max(score_width, 1)
        return cls(
            inst=torch.full((b, d), -1, dtype=long, device=dev),
            node=torch.full((b, d), graph.root, dtype=long, device=dev),  # (instance 0: the root)
            child=zeros(d, dtype=long),
            start_state=zeros(d, dtype=long),
            steps=zeros(d, dtype=long),
            time=zeros(d),
            reward=zeros(d),
            disc_reward=zeros(d),
            internal=zeros(d),
            greedy=torch.ones(b, d, dtype=flag, device=dev),
            own_greedy=torch.ones(b, d, dtype=flag, device=dev),
            inv_steps=zeros(d, dtype=long),
            vis_state=zeros(d, visits, dtype=long),
            vis_steps=zeros(d, visits, dtype=long),
            vis_time=zeros(d, visits),
            vis_internal=zeros(d, visits),
            start_features=zeros(d, max(graph.max_features, 1)),
            score_index=torch.full((b, d, k), -1, dtype=long, device=dev),
            score_value=zeros(d, k),
            top=torch.full((b,), -1, dtype=long, device=dev),
            done=zeros(dtype=flag),
            cont_action=zeros(max(graph.action_dim, 1)),
            memory=zeros(graph.n_nodes, max(graph.max_memory, 1)),
            batch_size=[b],
        )

    def cleared(self) -> TaskStack:
        """These stacks emptied: every row starts at the root on the next push."""
        out = self.clone(recurse=False)
        out.top = torch.full_like(self.top, -1)
        out.inst = torch.full_like(self.inst, -1)
        out.done = torch.zeros_like(self.done)
        return out

    def describe(self, graph: TaskGraph, row: int) -> str:
        """Row ``row``'s stack from the root to the top, e.g. ``Root/Get/Navigate_R/North``."""
        top = int(self.top[row])
        if top < 0:
            return "(empty)"
        return graph.instance_path(int(self.inst[row, top]))

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Every field (cloned), for exact resume."""
        return {k: v.clone() for k, v in self.to_dict().items()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> TaskStack:
        """A stack with ``state_dict``'s fields, which must have this stack's shapes."""
        mine = self.to_dict()
        if set(state) != set(mine):
            raise ValueError(f"Task-Stack fields {sorted(state)} != {sorted(mine)}")
        for k, v in state.items():
            if v.shape != mine[k].shape:
                raise ValueError(
                    f"Task-Stack field {k!r} has shape {tuple(v.shape)}, "
                    f"expected {tuple(mine[k].shape)}"
                )
        fields = {k: v.to(mine[k].device).clone() for k, v in state.items()}
        return type(self)(**fields, batch_size=self.batch_size)

    # -- fast access for the executor's hot path (a tensorclass attribute costs about 1-2 us)
    def tensors(self) -> dict[str, torch.Tensor]:
        """The fields as a new plain dict (the tensors are shared, not copied)."""
        return dict(self._tensordict._tensordict)

    @classmethod
    def from_tensors(cls, tensors: dict[str, torch.Tensor], batch: int) -> TaskStack:
        """A stack of ``batch`` rows made of ``tensors`` (as ``tensors()`` returns), unchecked."""
        return cls._from_tensordict(TensorDict._new_unsafe(tensors, batch_size=torch.Size([batch])))
