"""Settings as data: a learner, an exploration or an option group as "class + keyword arguments".

    Make(MaxQLearner, alpha=0.5, gamma=1.0, init=-20.0).build(graph, n_learners)
    # = MaxQLearner(graph, n_learners, alpha=0.5, gamma=1.0, init=-20.0)

A setting is a tree: a ``Make`` record's arguments and a dataclass's fields are its branches,
named with dots (``epsilon.end`` in ``Make(EpsilonGreedy, epsilon=Make(Linear, ...))``). Its
fields are the arguments given and those of the target's own defaults not filled by position,
so ``fields`` lists every value a build uses, and ``replace`` changes one by name, returning a
new tree (records are never changed in place: thread-safe). ``Budget`` keeps a schedule that
reads the training budget as data. Torch-free: the command-line parser may import it.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from types import FunctionType, MappingProxyType

__all__ = [
    "Budget",
    "Make",
    "fields",
    "parse_settings",
    "parse_value",
    "replace",
    "same",
    "split_name",
]


@dataclass(frozen=True)
class Budget:
    """A share of the training budget: ``floor(steps * fraction)`` env steps.

    ``Budget(Fraction(1, 3))`` is ``steps // 3`` exactly (a float ``1/3`` is not).
    """

    fraction: float | Fraction

    def __post_init__(self) -> None:
        if isinstance(self.fraction, bool) or not isinstance(self.fraction, int | float | Fraction):
            raise ValueError(f"Budget.fraction must be a number, got {self.fraction!r}")
        if not (math.isfinite(self.fraction) and self.fraction >= 0):
            raise ValueError(f"Budget.fraction must be finite and >= 0, got {self.fraction!r}")

    def of(self, steps: int) -> int:
        """The share of ``steps``."""
        return math.floor(steps * Fraction(self.fraction))


class Make:
    """``target(*positional, **kwargs)`` as data (``target``: a class or a function).

    ``build`` builds nested records first and turns ``Budget`` values into step counts.
    Compared by target and arguments; pickles (for Ray workers) when ``target`` does.
    """

    __slots__ = ("kwargs", "target")

    def __init__(self, target: Callable, /, **kwargs) -> None:
        if not callable(target):
            raise TypeError(f"Make needs a class or function, got {target!r}")
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "kwargs", MappingProxyType(dict(kwargs)))

    def __setattr__(self, name, value):
        raise dataclasses.FrozenInstanceError(f"Make is frozen: use config.replace ({name})")

    def __reduce__(self):
        return (_make, (self.target, dict(self.kwargs)))

    def __eq__(self, other) -> bool:
        if not isinstance(other, Make):
            return NotImplemented
        return self.target is other.target and same(dict(self.kwargs), dict(other.kwargs))

    __hash__ = None  # arguments may be unhashable (lists, tensors)

    def __repr__(self) -> str:
        args = "".join(f", {k}={v!r}" for k, v in self.kwargs.items())
        return f"Make({name_of(self.target)}{args})"

    def build(self, *positional, budget: int | None = None):
        """``target(*positional, **kwargs)``, nested records built with the same ``budget``."""
        kwargs = {k: _built(v, budget) for k, v in self.kwargs.items()}
        return self.target(*positional, **kwargs)

    def arguments(self, n_positional: int = 0) -> dict:
        """The arguments a build with ``n_positional`` positional values uses, by name.

        The given ones, then the target's defaults of the named parameters not given and not
        filled by position (a target without a signature: the given ones).
        """
        out = dict(self.kwargs)
        try:
            params = list(inspect.signature(self.target).parameters.values())
        except (TypeError, ValueError):
            return out
        named = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
        for p in params[n_positional:]:
            if p.kind in named and p.default is not p.empty and p.name not in out:
                out[p.name] = p.default
        return out

    def with_argument(self, name: str, value) -> Make:
        """A copy with ``name=value``."""
        return Make(self.target, **{**self.kwargs, name: value})


def same(a, b) -> bool:
    """Whether two settings are equal, tensors included (one per learner: equal entries).

    ``==`` on a tensor compares entry by entry, and a dict or list holding one then has no
    truth value; here tensors are equal when their dtype, shape and entries are.
    """
    torch = sys.modules.get("torch")  # no tensor exists unless torch was imported
    if torch is not None and isinstance(a, torch.Tensor):
        return (
            isinstance(b, torch.Tensor)
            and (a.dtype, a.shape) == (b.dtype, b.shape)
            and bool(torch.equal(a.cpu(), b.cpu()))
        )
    if torch is not None and isinstance(b, torch.Tensor):
        return False
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return type(a) is type(b) and len(a) == len(b) and all(map(same, a, b))
    if dataclasses.is_dataclass(a) and not isinstance(a, type):  # a schedule holding a tensor
        named = [f.name for f in dataclasses.fields(a)]
        return type(a) is type(b) and all(same(vars(a)[n], vars(b)[n]) for n in named)
    return bool(a == b)


def _make(target, kwargs: dict) -> Make:
    return Make(target, **kwargs)


def _built(value, budget: int | None):
    if isinstance(value, Make):
        return value.build(budget=budget)
    if isinstance(value, Budget):
        if budget is None:
            raise ValueError(f"{value} needs the training budget: build it with budget=steps")
        return value.of(budget)
    return value


def name_of(target) -> str:
    """A class's or function's name (others: their repr)."""
    return target.__qualname__ if isinstance(target, type | FunctionType) else repr(target)


def _branches(value, n_positional: int = 0) -> dict | None:
    """The named children of a tree node, or ``None`` for a leaf."""
    if isinstance(value, Make):
        return value.arguments(n_positional)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: vars(value)[f.name] for f in dataclasses.fields(value) if f.init}
    return None


def fields(value, prefix: str, n_positional: int = 0, classes: bool = True) -> dict:
    """Every leaf of a setting by dotted name, and (``classes``) each record's class at its own.

    ``fields(Make(EpsilonGreedy, epsilon=0.1), "exploration")`` ->
    ``{"exploration": "EpsilonGreedy", "exploration.epsilon": 0.1}``. ``n_positional``: how
    many positional values the top record's build gets (those parameters are not fields).
    """
    children = _branches(value, n_positional)
    if children is None:
        return {prefix: value}
    out = {prefix: name_of(value.target if isinstance(value, Make) else type(value))}
    if not classes:
        out = {}
    for name, child in children.items():
        out.update(fields(child, f"{prefix}.{name}", classes=classes))
    return out


def replace(value, path: str, new, n_positional: int = 0):
    """``value`` with the field at dotted ``path`` (below ``value``) set to ``new``.

    Dataclasses change by ``dataclasses.replace`` (their checks run), records by a new
    ``Make``; ``new`` is not checked (a number, a tensor, a record). ``KeyError`` names the
    first part of ``path`` that does not exist.
    """
    head, _, rest = path.partition(".")
    children = _branches(value, n_positional)
    if children is None or head not in children:
        raise KeyError(head)
    child = replace(children[head], rest, new) if rest else _same_kind(head, children[head], new)
    if isinstance(value, Make):
        return value.with_argument(head, child)
    return dataclasses.replace(value, **{head: child})


def _same_kind(name: str, old, new):
    """``new`` if it is of ``old``'s kind: a flag for a flag, a number for a number."""
    if isinstance(old, bool) and not isinstance(new, bool):
        raise ValueError(f"{name} is a flag (now {old}): give true or false, got {new!r}")
    if isinstance(old, int | float) and not isinstance(old, bool) and isinstance(new, bool):
        raise ValueError(f"{name} is a number (now {old}), got {new!r}")
    return new


def split_name(name: str) -> list[str] | None:
    """``"exploration.epsilon.end"`` -> its parts; ``None`` when a part is not an identifier."""
    parts = name.split(".")
    return parts if all(p.isidentifier() for p in parts) else None


def parse_value(item: str, text: str, what: str = "grid item") -> int | float | bool:
    """A command-line value: ``true``/``false``, a whole number (``int``) or a finite float.

    The ``ValueError`` names ``what`` and ``item`` (the whole ``NAME=...`` text).
    """
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not text:
        raise ValueError(f"{what} {item!r}: an empty value")
    if not math.isfinite(value):
        raise ValueError(f"{what} {item!r}: {text!r} is not a finite number (or true/false)")
    return value


def parse_settings(items: list[str], what: str = "--set") -> dict:
    """``["learner.alpha=0.2", "steps=100"]`` -> ``{"learner.alpha": 0.2, "steps": 100}``.

    Values as ``parse_value``; a malformed item or a name given twice is a one-line
    ``ValueError`` naming the item (whether the name exists, ``with_overrides`` says).
    """
    out: dict = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or split_name(name) is None:
            raise ValueError(f"{what} {item!r}: expected NAME=VALUE (e.g. learner.alpha=0.2)")
        if name in out:
            raise ValueError(f"{what} {item!r}: {name} is given twice")
        out[name] = parse_value(item, text.strip(), what)
    return out
