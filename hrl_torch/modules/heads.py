"""Heads: the learned tensors of one subtask, as ``nn.Module``s.

A learner keeps one head per subtask (per Task-Stack instance for hierarchically optimal
learners, per parameter group where subtasks share a policy) in ``learner.heads``, an
``nn.ModuleDict`` keyed by the subtask's name (an instance's path, ``Root/Get/Navigate_R``),
so the ``state_dict()`` of a trained learner names every subtask's tensors:
``heads.Navigate_R.C``, ``heads.Root/Get.CE``, ``heads.Diagonal.theta``. Heads live in the
learner, not in the task graph, so one graph can serve several learners.

For speed the tensors of one kind live in one flat bank per learner (``TableBank``, ``[P *
total + 1]``): a batch of updates from any mix of subtasks and learners stays one
``index_put_`` / ``index_add_``. A head owns a block of each bank and shows it as a view with
the population dimension first; the state dict holds the views, not the banks.

Two families:

- **value heads**: ``TableHead``, the tabular ``V`` / ``C`` / ``C_int`` / ``CE`` / ``Q`` (and
  HH-learning's model counts) of one table node, which the tabular learners read and write with
  their batched equations; ``TileValueHead``, a tile-coded value over features (the
  actor-critic's critic).
- **policy heads** (``PolicyHead``): a parameterised policy ``mu(a | s; theta)`` of a PG node.
  The policy-gradient learners route every PG node to its head: the head chooses and returns
  the likelihood-ratio term of its choice. ``hrl_torch.modules.policies`` has the softmax and the
  tile-coded Gaussian heads; a new kind of policy subclasses ``PolicyHead`` and overrides
  ``act`` (and ``check``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch
from torch import nn

from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.modules.tables import TableBank
from hrl_torch.modules.tiles import TileCoder


class Head(nn.Module):
    """Base class: named tensors of one subtask, saved and loaded as views of the banks.

    Subclasses return their tensors from ``views`` (population dimension first); the state
    dict holds them under the head's prefix, and loading copies into them in place.
    """

    def __init__(self, name: str) -> None:
        super().__init__()
        self.name = name

    def views(self) -> dict[str, torch.Tensor]:
        """The head's tensors by name (views into its learner's banks)."""
        return {}

    def _save_to_state_dict(self, destination, prefix, keep_vars) -> None:
        super()._save_to_state_dict(destination, prefix, keep_vars)
        for key, view in self.views().items():
            destination[prefix + key] = view if keep_vars else view.detach()

    def _load_from_state_dict(
        self, state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, errors
    ) -> None:
        super()._load_from_state_dict(
            state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, errors
        )
        for key, view in self.views().items():
            name = prefix + key
            if name in unexpected_keys:
                unexpected_keys.remove(name)
            if name not in state_dict:
                missing_keys.append(name)
            elif state_dict[name].shape != view.shape:
                errors.append(
                    f"size mismatch for {name}: copying a tensor of shape "
                    f"{tuple(state_dict[name].shape)}, the head's is {tuple(view.shape)}"
                )
            else:
                with torch.no_grad():
                    view.copy_(state_dict[name])

    def extra_repr(self) -> str:
        """The tensors' names and shapes."""
        return ", ".join(f"{k}={tuple(v.shape)}" for k, v in self.views().items())


class TableHead(Head):
    """The tabular tables of one table node: ``[P, S, A]`` views into the learner's banks.

    Args:
        name: the subtask's (or instance's) name.
        banks: the learner's banks by kind (``{"C": bank, "V": bank}``).
        table: the table node's index in the banks.
    """

    def __init__(self, name: str, banks: Mapping[str, TableBank], table: int) -> None:
        super().__init__(name)
        self.table = table
        # the banks belong to the learner: kept out of this module's children
        object.__setattr__(self, "_banks", dict(banks))

    def views(self) -> dict[str, torch.Tensor]:
        """``{kind: [P, n_states, n_cols]}`` for every bank holding this table."""
        return {kind: bank.block(self.table) for kind, bank in self._banks.items()}

    def __getitem__(self, kind: str) -> torch.Tensor:
        """One table, e.g. ``learner.heads["Navigate_R"]["C"]`` ``[P, S, A]``."""
        return self._banks[kind].block(self.table)


def attach_table_heads(
    learner: nn.Module, graph: TaskGraph, layout, banks: Mapping[str, TableBank]
) -> nn.ModuleDict:
    """One ``TableHead`` per table node holding entries in ``banks``; the banks stop saving.

    Per-subtask layouts name heads by subtask, per-instance layouts by instance path.
    """
    heads = nn.ModuleDict()
    for table in range(layout.n_tables):
        own = {k: b for k, b in banks.items() if b.block(table).numel() > 0}
        if not own:
            continue
        name = graph.instance_path(table) if layout.per_instance else graph.names[table]
        heads[name] = TableHead(name, own, table)
    for bank in banks.values():
        bank.save_store = False
    return heads


@dataclass
class PolicyInput:
    """What a policy head sees for the ``n`` rows that choose at its node(s).

    Attributes:
        base: flat offset of each row's parameter block in ``theta`` (its learner's copy of
            the head's parameters) ``[n]``.
        state: abstract state of the choosing node ``[n]``.
        features: the node's continuous features ``[n, F]`` (``None`` without features).
        available: available children ``[n, A]``.
        u: uniforms in ``[0, 1)`` ``[n, W]``, the row's random numbers for this choice (``W``:
            the largest ``n_uniforms`` of the learner's heads, at least 3).
        step: env steps per learner (for schedules).
    """

    base: torch.Tensor
    state: torch.Tensor
    features: torch.Tensor | None
    available: torch.Tensor
    u: torch.Tensor
    step: int


@dataclass
class PolicyChoice:
    """A policy head's choices for ``n`` rows and their likelihood-ratio terms.

    Attributes:
        child: the chosen child slot ``[n]``.
        greedy: the choice is the policy's mode ``[n]``.
        action: the continuous action ``[n]``, or ``[n, D]`` for an action vector (heads of
            continuous primitives), or ``None``.
        index: flat indices into ``theta`` of the score's nonzero entries ``[n, K]`` (pad
            with the learner's sentinel index, ``theta.numel() - 1``).
        score: ``grad mu(a|s) / mu(a|s)`` at those entries ``[n, K]`` (Equation 5.3).
    """

    child: torch.Tensor
    greedy: torch.Tensor
    action: torch.Tensor | None
    index: torch.Tensor
    score: torch.Tensor


class PolicyHead(Head):
    """A parameterised policy ``mu(a | s; theta)`` of one PG node (or a group sharing it).

    Each learner of the population owns a ``[n_states, n_cols]`` block of the PG learner's
    flat ``theta``; ``act`` reads it at ``theta[base + ...]``. Subclasses set ``width`` (the
    nonzeros of one choice's score) and ``continuous`` (the node's child is a continuous
    primitive), and override ``act``; ``check`` rejects nodes the head cannot serve. Heads
    whose ``batch_key`` agree are evaluated in one ``act`` call over all their rows (each row's
    ``base`` points at its own head's block).

    Args:
        name: the head's name (its subtask or group).
        n_states: rows of the parameter block.
        n_cols: columns of the parameter block.
    """

    width: int = 1
    continuous: bool = False
    #: uniforms per row a choice reads (``PolicyInput.u``; the learner draws the largest)
    n_uniforms: int = 3
    #: the head steps its parameters itself (``optimizer_step``), not by ``alpha F``
    steps_itself: bool = False

    def __init__(self, name: str, n_states: int, n_cols: int) -> None:
        super().__init__(name)
        self.n_states, self.n_cols = int(n_states), int(n_cols)
        #: the columns in use (a subclass whose block is wider than its choices narrows it)
        self.n_children = self.n_cols
        self.table = -1
        object.__setattr__(self, "_bank", None)

    def bind(self, bank: TableBank, table: int) -> None:
        """Store the parameters in block ``table`` of the learner's ``bank``."""
        object.__setattr__(self, "_bank", bank)
        self.table = table

    def views(self) -> dict[str, torch.Tensor]:
        """``{"theta": [P, n_states, n_cols]}``."""
        return {} if self._bank is None else {"theta": self._bank.block(self.table)}

    def batch_key(self) -> object:
        """Heads with equal keys share one ``act`` call (default: none share)."""
        return id(self)

    def check(self, graph: TaskGraph, node: int) -> None:
        """Raise ``GraphError`` if this head cannot choose for ``graph`` node ``node``."""

    def act(self, theta: torch.Tensor, inp: PolicyInput, greedy: bool) -> PolicyChoice:
        """Choose for the rows of ``inp``: sample (``greedy=False``) or take the mode."""
        raise NotImplementedError

    def optimizer_step(self, estimate: torch.Tensor) -> torch.Tensor:
        """The step ``[P, K]`` of the head's parameters for a gradient estimate ``[P, K]``.

        Called after every update when ``steps_itself`` (e.g. Adam); by default Algorithm 3's
        own step is used and this is not called.
        """
        raise NotImplementedError


class TileValueHead(Head):
    """A tile-coded value ``Q(x) = mean_i w[tile_i(x)]``: ``w [P, n_tiles]`` in a flat bank.

    Args:
        name: the head's name.
        coder: the tile coder of the inputs ``x``.
        n_learners: population size ``P``.
    """

    def __init__(self, name: str, coder: TileCoder, n_learners: int) -> None:
        super().__init__(name)
        self.coder = coder
        self.n_features = coder.n_features
        n = torch.ones(1, dtype=torch.long)
        self.bank = TableBank(n_learners, n, n * coder.n_features)
        self.bank.save_store = False

    @property
    def w(self) -> torch.Tensor:
        """The flat weights ``[P * n_tiles + 1]`` (last entry: a sentinel that stays 0)."""
        return self.bank.store

    def views(self) -> dict[str, torch.Tensor]:
        """``{"w": [P, n_tiles]}``."""
        return {"w": self.bank.block(0)[:, 0]}

    def tiles(self, learner: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Flat indices ``[n, T]`` into ``w`` of the active tiles of ``x [n, D]``."""
        return self.coder(x) + (learner * self.n_features)[:, None]

    def value(self, tiles: torch.Tensor) -> torch.Tensor:
        """``Q`` at flat tiles ``[n, T]``: ``[n]``."""
        return self.w[tiles].mean(-1)

    def add(self, tiles: torch.Tensor, step: torch.Tensor) -> None:
        """``w[tile] += step`` for every tile of each row (``step [n]``; sentinel stays 0)."""
        self.w.index_add_(0, tiles.reshape(-1), step[:, None].expand_as(tiles).reshape(-1))
        self.w[-1:].zero_()  # (the sentinel; no tensor from host data)
