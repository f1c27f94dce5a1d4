"""The nodes of a task graph: subtasks and primitive actions (Definition 3.1).

A non-primitive subtask is ``M_i = (S_i, I_i, T_i, A_i, R_i)`` (Definition 3.1): an abstract state
space (``abstract`` maps an observation to ``[0, n_states)``), an initiation set (``initiable``),
terminal states (``terminated``), children (``children`` plus an optional per-state ``child_mask``
for ``A_i(s)``) and internal rewards (``pseudo_reward`` on termination, ``shaping_reward`` per
step) that are used inside the subtask only. ``hrl_torch.hierarchy.graph.TaskGraph`` puts them
together.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDict
from torch import nn

ObsFn = Callable[[TensorDict], torch.Tensor]


class GraphError(ValueError):
    """An invalid task graph, or a subtask that misbehaves at run time."""


def batch_and_device(obs: TensorDict) -> tuple[int, torch.device]:
    """``obs``'s number of rows and its device (the CPU when it has none)."""
    return obs.batch_size[0], obs.device if obs.device is not None else torch.device("cpu")


class Subtask(nn.Module):
    """A non-primitive subtask. Subclass it, or pass the predicates as callables.

    Args:
        name: unique name in the graph.
        children: names of child subtasks or primitives (the action set ``A_i``).
        n_states: size of the abstract state space ``S_i``.
        abstract: ``obs -> [B] long`` in ``[0, n_states)``; required when ``n_states > 1``.
        terminated: ``obs -> [B] bool``, the terminal set ``T_i`` (default: never, as a
            continuing root).
        initiable: ``obs -> [B] bool``, the initiation set ``I_i`` (default: everywhere).
        child_mask: ``obs -> [B, n_children] bool``, the state-dependent action set ``A_i(s)``.
        pseudo_reward: ``obs -> [B]``, internal reward on entering a terminal state (MAXQ).
        shaping_reward: ``(obs, action, next_obs) -> [B]``, internal reward per primitive step.
        event_termination: the predicate marks an *event* of the last step (e.g. "a part was
            delivered") rather than a terminal *state*: it ends a running invocation but does
            not make the subtask unavailable, or worth zero, where it holds.
        features: ``obs -> [B, n_features]`` float, a continuous state description for
            function approximation (policy-gradient nodes), beside the discrete ``abstract``.
        n_features: width of ``features``.
        remember: ``obs -> [B, memory_size]``, what an invocation records when it starts (e.g.
            the position it started from, to steer in a local frame). With
            ``memory_size > 0``, ``terminated``, ``features`` and ``pseudo_reward`` receive
            ``(obs, memory)`` and ``shaping_reward`` ``(obs, action, next_obs, memory)``.
            Such a subtask's termination depends on where it started, so it never blocks a
            start (as with ``event_termination``).
        memory_size: width of ``remember``.
    """

    is_primitive = False
    event_termination = False
    memory_size = 0

    def __init__(
        self,
        name: str,
        children: Sequence[str],
        n_states: int = 1,
        *,
        abstract: ObsFn | None = None,
        terminated: ObsFn | None = None,
        initiable: ObsFn | None = None,
        child_mask: ObsFn | None = None,
        pseudo_reward: ObsFn | None = None,
        shaping_reward: Callable[[TensorDict, torch.Tensor, TensorDict], torch.Tensor]
        | None = None,
        event_termination: bool | None = None,
        features: ObsFn | None = None,
        n_features: int = 0,
        remember: ObsFn | None = None,
        memory_size: int = 0,
    ) -> None:
        super().__init__()
        self.name = name
        self.n_features = int(n_features)
        if memory_size:
            self.memory_size = int(memory_size)
        if event_termination is not None:
            self.event_termination = bool(event_termination)
        self.children_names = tuple(children)
        self.n_states = int(n_states)
        self._fns = {
            "abstract": abstract,
            "terminated": terminated,
            "initiable": initiable,
            "child_mask": child_mask,
            "pseudo_reward": pseudo_reward,
            "shaping_reward": shaping_reward,
            "features": features,
            "remember": remember,
        }

    def _with_memory(self, fn, obs: TensorDict, memory: torch.Tensor | None):
        return fn(obs, memory) if self.memory_size else fn(obs)

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        """Abstract state index in ``[0, n_states)``, shape ``[B]``."""
        if self._fns["abstract"] is not None:
            return self._fns["abstract"](obs)
        if self.n_states != 1:
            raise GraphError(
                f"subtask {self.name!r} has n_states={self.n_states} but no abstract()"
            )
        b, device = batch_and_device(obs)
        return torch.zeros(b, dtype=torch.long, device=device)

    def remember(self, obs: TensorDict) -> torch.Tensor | None:
        """What a new invocation records, ``[B, memory_size]`` (``None`` without memory)."""
        fn = self._fns["remember"]
        if fn is None:
            if self.memory_size:
                raise GraphError(f"subtask {self.name!r} has memory_size but no remember()")
            return None
        return fn(obs)

    def features(self, obs: TensorDict, memory: torch.Tensor | None = None) -> torch.Tensor | None:
        """Continuous state features ``[B, n_features]`` (``None`` when ``n_features == 0``)."""
        fn = self._fns["features"]
        if fn is None:
            if self.n_features:
                raise GraphError(f"subtask {self.name!r} has n_features but no features()")
            return None
        return self._with_memory(fn, obs, memory)

    def terminated(self, obs: TensorDict, memory: torch.Tensor | None = None) -> torch.Tensor:
        """Whether ``obs`` is in the terminal set ``T_i``, shape ``[B]``."""
        if self._fns["terminated"] is not None:
            return self._with_memory(self._fns["terminated"], obs, memory)
        b, device = batch_and_device(obs)
        return torch.zeros(b, dtype=torch.bool, device=device)

    def initiable(self, obs: TensorDict) -> torch.Tensor:
        """Whether ``obs`` is in the initiation set ``I_i``, shape ``[B]``."""
        if self._fns["initiable"] is not None:
            return self._fns["initiable"](obs)
        b, device = batch_and_device(obs)
        return torch.ones(b, dtype=torch.bool, device=device)

    def child_mask(self, obs: TensorDict) -> torch.Tensor | None:
        """``A_i(s)`` as ``[B, n_children]`` bool, or ``None`` when every child is allowed."""
        fn = self._fns["child_mask"]
        return None if fn is None else fn(obs)

    def pseudo_reward(
        self, obs: TensorDict, memory: torch.Tensor | None = None
    ) -> torch.Tensor | None:
        """Internal reward for terminating in ``obs`` (``None`` means zero)."""
        fn = self._fns["pseudo_reward"]
        return None if fn is None else self._with_memory(fn, obs, memory)

    def shaping_reward(
        self,
        obs: TensorDict,
        action: torch.Tensor,
        next_obs: TensorDict,
        memory: torch.Tensor | None = None,
    ) -> torch.Tensor | None:
        """Internal reward for one primitive step inside this subtask (``None`` means zero)."""
        fn = self._fns["shaping_reward"]
        if fn is None:
            return None
        return fn(obs, action, next_obs, memory) if self.memory_size else fn(obs, action, next_obs)

    def has_shaping_rewards(self) -> bool:
        """Whether this subtask defines per-step shaping rewards."""
        return overrides(self, "shaping_reward")

    def has_internal_rewards(self) -> bool:
        """Whether this subtask defines pseudo or shaping rewards (so internal != external)."""
        cls = type(self)
        overridden = (
            cls.pseudo_reward is not Subtask.pseudo_reward
            or cls.shaping_reward is not Subtask.shaping_reward
        )
        given = self._fns["pseudo_reward"] is not None or self._fns["shaping_reward"] is not None
        return overridden or given

    def extra_repr(self) -> str:
        """Shown by ``print(module)``."""
        return f"name={self.name!r}, children={list(self.children_names)}, n_states={self.n_states}"


class Primitive(nn.Module):
    """A primitive action: always executable, terminates after one step.

    Args:
        name: unique name in the graph.
        action: the env action index it executes (discrete action spaces).
        n_states: size of the abstract state space of its value table ``V(a, s)``; the default
            1 says its expected reward does not depend on the state (Dietterich's leaf
            irrelevance).
        abstract: ``obs -> [B] long``; required when ``n_states > 1``.
        action_dim: for a continuous action space, the width of the action vector; its value is
            chosen by the parent's policy when the primitive is pushed (``action`` unused).
    """

    is_primitive = True
    children_names: tuple[str, ...] = ()
    n_features = 0
    memory_size = 0
    event_termination = False

    def __init__(
        self,
        name: str,
        action: int = -1,
        n_states: int = 1,
        abstract: ObsFn | None = None,
        action_dim: int = 0,
    ):
        super().__init__()
        self.name = name
        self.action = int(action)
        self.action_dim = int(action_dim)
        self.n_states = int(n_states)
        self._abstract = abstract

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        """Abstract state index of ``V(a, s)``, shape ``[B]``."""
        if self._abstract is not None:
            return self._abstract(obs)
        if self.n_states != 1:
            raise GraphError(
                f"primitive {self.name!r} has n_states={self.n_states} but no abstract"
            )
        b, device = batch_and_device(obs)
        return torch.zeros(b, dtype=torch.long, device=device)

    def has_internal_rewards(self) -> bool:
        """Primitives carry no internal rewards."""
        return False

    def extra_repr(self) -> str:
        """Shown by ``print(module)``."""
        return f"name={self.name!r}, action={self.action}, n_states={self.n_states}"


Node = Subtask | Primitive


def overrides(node: Node, method: str) -> bool:
    """Whether ``node`` defines ``method`` itself (subclass override or a callable given)."""
    base = Primitive if node.is_primitive else Subtask
    if _defined(type(node), method) is not vars(base)[method]:
        return True
    if node.is_primitive:
        return method == "abstract" and node._abstract is not None
    return node._fns.get(method) is not None


def _defined(cls: type, name: str):
    """The class attribute ``name`` as ``cls`` finds it: the first definition along its MRO."""
    return next(vars(c)[name] for c in cls.__mro__ if name in vars(c))
