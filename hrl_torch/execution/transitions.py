"""The contract between the executor, its policies and the learners, declared in code.

A *transition batch* is what ``HierarchicalExecutor.observe`` emits and ``Learner.update``
reads: a TensorDict ``[B]`` with ``learner [B]`` and two nested TensorDicts, ``batch[LEVEL]``
``[B, D]`` (level ``j``: the subtask whose child ended) and ``batch[PRIMITIVE]`` ``[B]`` (the
primitive step just taken). ``LEVEL_KEYS`` and ``PRIMITIVE_KEYS`` declare every key with its
shape and dtype, and when it is present (``Key.when``):

- ``None``: always;
- one of ``OPTIONAL`` (``parent_inst``, ``next_state``, ``truncated``, ``greedy``,
  ``primitive``): only when the executor's ``uses`` (a learner's ``Learner.uses``) names it;
- ``"visited"``: with ``ExecutorConfig.record_visited = L > 0`` (all-states updating);
- ``"features"``: on a graph with feature nodes (``Subtask.features``);
- ``"score"``: with a policy that scores its choices (PG nodes, ``score_width = K > 0``).

Shapes are written with ``B`` (rows), ``D`` (stack depth), ``L`` (visits kept), ``F``
(features), ``K`` (score width) and ``A`` (continuous action size; a discrete action is
``[B]``). ``check_transitions`` checks a batch against the declaration (tests use it on every
executor configuration).

A policy chooses children (``Policy.select``, returning a ``Choice``); the executor uses two
optional capabilities when a policy has them: ``ChoosesAll`` and ``SelectsRows``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import torch
from tensordict import TensorDict

if TYPE_CHECKING:
    from hrl_torch.hierarchy.graph import StepContext

#: key of the per-level transitions ``[B, D]`` in a transition batch
LEVEL = "level"
#: key of the primitive step ``[B]`` in a transition batch
PRIMITIVE = "primitive"
#: transition keys computed only when asked for (the executor's ``uses``): ``batch[LEVEL]``'s
#: ``parent_inst``, ``next_state``, ``truncated``; ``"greedy"`` for the greedy flags
#: (``greedy``, ``own_greedy`` of both parts); ``"primitive"`` for ``batch[PRIMITIVE]``'s
#: fields other than ``reward`` and ``duration``
OPTIONAL = frozenset({"parent_inst", "next_state", "truncated", "greedy", "primitive"})


@dataclass(frozen=True)
class Key:
    """One declared transition key.

    Attributes:
        name: the key.
        shape: symbolic dims (``"B"``, ``"D"``, ``"L"``, ``"F"``, ``"K"``, ``"A"``).
        dtype: ``"bool"``, ``"long"`` or ``"float"`` (any floating type).
        when: when it is present (see the module docstring; ``None``: always).
        doc: what it holds.
    """

    name: str
    shape: tuple[str, ...]
    dtype: str
    when: str | None
    doc: str


_BD = ("B", "D")
_BDL = ("B", "D", "L")
LEVEL_KEYS: tuple[Key, ...] = (
    Key("valid", _BD, "bool", None, "a transition was emitted at this level"),
    Key("inst", _BD, "long", None, "the level's instance"),
    Key("node", _BD, "long", None, "its graph node"),
    Key("child", _BD, "long", None, "the slot of the child that ended, among its children"),
    Key("state", _BD, "long", None, "abstract state of node when the child started"),
    Key("steps", _BD, "long", None, "primitive steps N the child took"),
    Key("duration", _BD, "float", None, "time tau the child took"),
    Key("reward", _BD, "float", None, "external reward, summed"),
    Key("discounted_reward", _BD, "float", None, "sum of gamma**t r"),
    Key("internal_reward", _BD, "float", None, "discounted shaping of node"),
    Key("pseudo_reward", _BD, "float", None, "node's pseudo reward if s' is terminal for it"),
    Key("terminal", _BD, "bool", None, "s' is terminal for node"),
    Key("child_done", _BD, "bool", None, "the child ended by its own termination, no abort"),
    Key("ran", _BD, "bool", None, "the level holds the primitive that ran (state: its own)"),
    Key("parent_inst", _BD, "long", "parent_inst", "the instance one level up (-1: none)"),
    Key("next_state", _BD, "long", "next_state", "abstract state of node at s'"),
    Key("truncated", _BD, "bool", "truncated", "a time limit ended the episode at s'"),
    Key("greedy", _BD, "bool", "greedy", "the child and all its ancestors chosen greedily"),
    Key("own_greedy", _BD, "bool", "greedy", "the child was chosen greedily"),
    Key("visited_state", _BDL, "long", "visited", "states of node during the child"),
    Key("visited_steps", _BDL, "long", "visited", "their step counts since the start"),
    Key("visited_time", _BDL, "float", "visited", "their times since the start"),
    Key(
        "visited_internal",
        _BDL,
        "float",
        "visited",
        "the node's discounted shaping reward before each, to the child's start",
    ),
    Key("visited_valid", _BDL, "bool", "visited", "the visit slot holds a visit"),
    Key("features", ("B", "D", "F"), "float", "features", "node's features at the start"),
    Key("next_features", ("B", "D", "F"), "float", "features", "node's features at s'"),
    Key("score_index", ("B", "D", "K"), "long", "score", "likelihood-ratio term: indices"),
    Key("score_value", ("B", "D", "K"), "float", "score", "likelihood-ratio term: values"),
)

PRIMITIVE_KEYS: tuple[Key, ...] = (
    Key("reward", ("B",), "float", None, "the step's reward"),
    Key("duration", ("B",), "float", None, "the step's duration"),
    Key("valid", ("B",), "bool", "primitive", "a real step with a primitive on top"),
    Key("inst", ("B",), "long", "primitive", "the primitive's instance"),
    Key("node", ("B",), "long", "primitive", "its graph node"),
    Key("state", ("B",), "long", "primitive", "its abstract state"),
    Key("action", ("B",), "long", "primitive", "the env action ([B, A] float if continuous)"),
    Key("greedy", ("B",), "bool", ("primitive", "greedy"), "parent and ancestors greedy"),
)


class TransitionSchemaError(ValueError):
    """A transition batch that does not match the declared keys."""


def present(key: Key, uses: frozenset[str], conditions: frozenset[str]) -> bool:
    """Whether ``key`` is in a batch of an executor with ``uses`` and ``conditions``.

    ``conditions``: the ones that hold among ``"visited"``, ``"features"``, ``"score"``.
    """
    needs = key.when if isinstance(key.when, tuple) else (key.when,)
    return all(n is None or n in uses or n in conditions for n in needs)


def check_transitions(batch, uses: frozenset[str], sizes: dict[str, int]) -> None:
    """Check ``batch``'s keys, shapes and dtypes against ``LEVEL_KEYS`` / ``PRIMITIVE_KEYS``.

    ``sizes`` gives ``B`` and ``D`` and, where they apply, ``L``, ``F``, ``K`` (their presence
    switches the conditional keys on) and ``A`` (continuous actions). Raises
    ``TransitionSchemaError`` naming every mismatch.
    """
    conditions = {"L": "visited", "F": "features", "K": "score"}
    on = frozenset(c for d, c in conditions.items() if sizes.get(d))
    problems = []
    for part, keys in ((LEVEL, LEVEL_KEYS), (PRIMITIVE, PRIMITIVE_KEYS)):
        td = batch[part]
        want = {k.name: k for k in keys if present(k, uses, on)}
        for extra in sorted(set(td.keys()) - set(want)):
            problems.append(f"{part}.{extra}: not declared for this executor")
        for name, key in want.items():
            if name not in td.keys():
                problems.append(f"{part}.{name}: missing")
                continue
            problems += _check_value(f"{part}.{name}", key, td[name], sizes)
    if problems:
        raise TransitionSchemaError("transition batch:\n  " + "\n  ".join(problems))


def _check_value(where: str, key: Key, value: torch.Tensor, sizes: dict[str, int]) -> list[str]:
    shape, dtype = key.shape, key.dtype
    if where == f"{PRIMITIVE}.action" and sizes.get("A"):  # continuous actions
        shape, dtype = ("B", "A"), "float"
    expected = tuple(sizes[d] for d in shape)
    kind = {"bool": value.dtype == torch.bool, "long": value.dtype == torch.long}
    ok = kind.get(dtype, value.dtype.is_floating_point)
    out = []
    if tuple(value.shape) != expected:
        out.append(f"{where}: shape {tuple(value.shape)}, declared {shape} = {expected}")
    if not ok:
        out.append(f"{where}: dtype {value.dtype}, declared {dtype}")
    return out


class TransitionWriter:
    """Builds one executor's transition batches (the keys declared above) from its stacks.

    ``HierarchicalExecutor.observe`` calls ``emit`` with its stack fields ``f`` and the step's
    masks; ``record_visits`` keeps the states visited during each child (all-states updating).
    It reads the executor's public settings (``graph``, ``uses``, ``config``, ``learner``).
    """

    def __init__(self, executor) -> None:
        self.executor = executor
        g, device = executor.graph, executor.graph.node_children.device
        size = max(executor.config.record_visited, 1)
        #: the visit slots ``[L]`` (visit ``k`` of a child lives in slot ``k % L``)
        self.visit_slots = torch.arange(size, dtype=torch.long, device=device)
        self._no_reward = torch.zeros(executor.batch_size, g.max_levels, device=device)

    def record_visits(self, f: dict, continuing, ctx: StepContext, node) -> None:
        """Append ``s'`` to the visit buffer of the levels whose child goes on.

        ``s'`` is abstracted for each level's node; visit ``k`` of a child lives in slot
        ``k % L``.
        """
        size = self.executor.config.record_visited
        slot = (f["steps"] % size).unsqueeze(-1)  # steps already counts this step: visit index
        here = continuing[..., None] & (self.visit_slots == slot)
        state = ctx.abstract.gather(1, node)
        for key, value in (
            ("vis_state", state),
            ("vis_steps", f["steps"]),
            ("vis_time", f["time"]),
            ("vis_internal", f["internal"]),
        ):
            f[key] = torch.where(here, value[..., None].to(f[key].dtype), f[key])

    def emit(self, f, step, ctx, emit, child_done, terminal, trunc, real, ran):
        """The finished SMDP transitions of this step (the keys declared above)."""
        ex = self.executor
        g, b, node = ex.graph, ex.batch_size, f["node"]
        if g.internal_nodes:
            pseudo = g.internal_rewards_at_termination(ctx.obs, f["memory"]).gather(1, node)
            pseudo = pseudo * terminal
        else:
            pseudo = self._no_reward
        level = {
            "valid": emit,
            "inst": f["inst"],
            "node": node,
            "child": f["child"],
            "state": f["start_state"],
            "steps": f["steps"],
            "duration": f["time"],
            "reward": f["reward"],
            "discounted_reward": f["disc_reward"],
            "internal_reward": f["internal"],
            "pseudo_reward": pseudo,
            "terminal": terminal,
            "child_done": child_done,
            "ran": ran,
        }
        uses = ex.uses
        if "parent_inst" in uses:
            level["parent_inst"] = shift_right(f["inst"], fill=-1)
        if "next_state" in uses:
            level["next_state"] = ctx.abstract.gather(1, node)
        if "truncated" in uses:
            level["truncated"] = trunc[:, None] & emit & ~terminal  # (a termination: terminal)
        if "greedy" in uses:
            level["greedy"], level["own_greedy"] = f["greedy"], f["own_greedy"]
        if ctx.features is not None:
            level["features"] = f["start_features"]
            level["next_features"] = ctx.features.gather(
                1, node[..., None].expand(-1, -1, ctx.features.shape[2])
            )
        if ex.score_width:
            level["score_index"] = f["score_index"]
            level["score_value"] = f["score_value"]
        if ex.config.record_visited:
            level.update(
                visited_state=f["vis_state"],
                visited_steps=f["vis_steps"],
                visited_time=f["vis_time"],
                visited_internal=f["vis_internal"],
                visited_valid=self.visit_slots
                < f["steps"].clamp_max(ex.config.record_visited)[..., None],
            )
        size = torch.Size([b])
        return TensorDict._new_unsafe(
            {
                "learner": ex.learner,
                LEVEL: TensorDict._new_unsafe(level, batch_size=torch.Size([b, ex.depth])),
                PRIMITIVE: TensorDict._new_unsafe(self._primitive(f, step, real, ran), size),
            },
            batch_size=size,
        )

    def _primitive(self, f: dict, step: dict, real, ran) -> dict:
        """The fields of the primitive step each row just took (``batch[PRIMITIVE]``).

        ``ran [B, D]`` marks the level of the primitive (its ``state`` reads 0 where the step
        teaches nothing). Only ``reward`` and ``duration`` unless ``"primitive"`` is used.
        """
        out = {"reward": step["reward"], "duration": step["duration"]}
        uses = self.executor.uses
        if "primitive" not in uses:
            return out
        g, top = self.executor.graph, f["top"]
        top1 = f["inst"].amax(1) + 1  # the instance on top, + 1
        out.update(
            valid=real & (top >= 0),
            inst=top1 - 1,
            node=torch.take(g.inst_node_1, top1),
            state=(f["start_state"] * ran).sum(1),
            action=f["cont_action"] if g.action_dim else torch.take(g.inst_action_1, top1),
        )
        if "greedy" in uses:
            out["greedy"] = f["own_greedy"].all(1)  # the levels at and above the top hold True
        return out


@dataclass
class Choice:
    """A policy's choices for the ``B`` rows of one push.

    Attributes:
        child: chosen child slot ``[B]`` (ignored for rows that do not push).
        greedy: the choice is the policy's greedy one ``[B]``.
        action: ``[B, action_dim]``, the action value of rows whose child is a continuous
            primitive (graphs with continuous primitives), else ``None``.
        score_index: ``[B, K]`` flat parameter indices of the choice's likelihood-ratio term
            (policy-gradient nodes), kept on the stack until the child ends; else ``None``.
        score_value: ``[B, K]`` its values.
    """

    child: torch.Tensor
    greedy: torch.Tensor
    action: torch.Tensor | None = None
    score_index: torch.Tensor | None = None
    score_value: torch.Tensor | None = None


def as_choice(out) -> Choice:
    """A policy's ``select`` result as a ``Choice`` (tuples ``(child, greedy[, action])``)."""
    if isinstance(out, Choice):
        return out
    return Choice(out[0], out[1], out[2] if len(out) > 2 else None)


class Policy(Protocol):
    """Chooses children for the instances on top of the stacks."""

    def new_step(self) -> None:
        """Called once at the start of every ``act`` (draw this step's random numbers)."""
        ...

    def select(
        self, inst: torch.Tensor, ctx: StepContext, available: torch.Tensor, step: int, push: int
    ) -> Choice:
        """The choices for instances ``inst [B]`` among ``available [B, A]`` children.

        ``push`` is the stack level (depth) of the instances that choose; rows whose instance
        does not choose at this level get any value (ignored). (A tuple ``(child, greedy[,
        action])`` is accepted too.)
        """
        ...


_KINDS: dict[tuple[type, type], bool] = {}


def is_kind(policy, protocol: type) -> bool:
    """``isinstance(policy, protocol)`` for a runtime-checkable protocol, kept per class.

    (A protocol's ``isinstance`` looks its methods up every call, several microseconds; the
    executor asks every step. Policies have their methods on their class.)
    """
    key = (type(policy), protocol)
    known = _KINDS.get(key)
    if known is None:
        known = _KINDS[key] = isinstance(policy, protocol)
    return known


@runtime_checkable
class ChoosesAll(Protocol):
    """A policy that can choose for every choosing instance at once."""

    def choose_all(self, ctx: StepContext, step: int) -> Choice | None:
        """The choices ``[B, Ic]`` of every instance of ``graph.choosers``, or ``None``.

        The executor follows them down the stacks (``None``: it asks ``select``).
        """
        ...


@runtime_checkable
class SelectsRows(Protocol):
    """A policy that can choose for some batch rows only (used on large CPU batches)."""

    def select_rows(self, inst, ctx: StepContext, available, step: int, push: int, rows):
        """``select`` for the batch rows ``rows [R]`` only.

        ``inst`` and ``available`` are those rows'; the choices are the ones ``select`` makes
        for them.
        """
        ...


@runtime_checkable
class PricesChoices(Protocol):
    """A policy that subtracts a fixed cost of choosing a child from its value before choosing.

    (``ValuePolicy``; COM-Cooperative HRL's communication cost sets it.)
    """

    #: ``[n_nodes, max_children]`` cost of each (node, child slot), or ``None``: no cost
    choice_cost: torch.Tensor | None


def shift_right(x: torch.Tensor, fill=0) -> torch.Tensor:
    """``x`` moved one level down the stack dims ``[B, D]`` (level 0 gets ``fill``)."""
    return torch.nn.functional.pad(x[:, :-1], (1, 0), value=fill)
