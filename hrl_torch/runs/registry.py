"""Domains by name: built in, from installed plugins, or from a module named on the CLI.

- Built-in domains (the repository's ``agents`` package) register by import string
  (``register("taxi", "agents.taxi:DOMAIN")``, imported on first use).
- A plugin is an installed package that declares its domains in the entry-point group
  ``hrl_torch.domains`` (``corridor = "hrl_corridor:DOMAIN"`` in its ``pyproject.toml``);
  ``load_plugins`` registers them.
- ``load_module("my_domains")`` imports a module and registers every ``DomainSpec`` it defines
  as ``DOMAIN`` or in ``DOMAINS`` (or that it registers itself on import).
"""

from __future__ import annotations

import importlib
import sys
from importlib.metadata import entry_points

from hrl_torch.runs.domain import DomainSpec

ENTRY_POINT_GROUP = "hrl_torch.domains"

_DOMAINS: dict[str, str | DomainSpec] = {}
_SOURCES: dict[str, str] = {}


def register(name: str, entry: str | DomainSpec, source: str = "built-in") -> None:
    """Register domain ``name`` as ``"module:attribute"`` (imported on first use) or a spec.

    Raises ``ValueError`` when another source already registered another domain as ``name``
    (an installed plugin's module named again with ``--domain-module`` is the same domain).
    """
    if isinstance(entry, str) and ":" not in entry:
        raise ValueError(f"entry must look like 'module:attribute', got {entry!r}")
    if isinstance(entry, DomainSpec) and entry.name != name:
        raise ValueError(_misnamed(name, entry.name, source))
    if name in _DOMAINS and _same(_DOMAINS[name], entry):
        return  # registered already, under its first source
    if name in _DOMAINS:
        raise ValueError(
            f"domain {name!r} is registered twice: {_describe(_DOMAINS[name])} "
            f"({_SOURCES[name]}) and {_describe(entry)} ({source}); rename one"
        )
    _DOMAINS[name] = entry
    _SOURCES[name] = source


def load_plugins() -> list[str]:
    """Register the domains of installed plugins (group ``hrl_torch.domains``); their names."""
    found = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        dist = ep.dist.name if ep.dist is not None else "?"
        register(ep.name, ep.value, source=f"plugin {dist}")
        found.append(ep.name)
    return found


def load_module(module: str) -> list[str]:
    """Import ``module`` and register its ``DOMAIN`` / ``DOMAINS``; the names it added.

    Raises ``ModuleNotFoundError`` for a module that cannot be imported and ``ValueError`` for
    one that defines and registers no domain.
    """
    before = set(_DOMAINS)
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name == module:
            raise
        raise ValueError(f"module {module!r} failed to import: {_first_line(err)}") from err
    except Exception as err:  # a module that raises while it imports: one line, not a traceback
        raise ValueError(f"module {module!r} failed to import: {_first_line(err)}") from err
    found = vars(mod)
    specs = list(found.get("DOMAINS", []))
    if isinstance(found.get("DOMAIN"), DomainSpec):
        specs.append(found["DOMAIN"])
    for spec in specs:
        register(spec.name, spec, source=f"module {module}")
    added = sorted(set(_DOMAINS) - before)
    if not added and not specs:
        raise ValueError(f"module {module!r} defines no DOMAIN or DOMAINS (DomainSpec)")
    return added


def names() -> list[str]:
    """Registered domain names."""
    return sorted(_DOMAINS)


def source(name: str) -> str:
    """Where domain ``name`` came from: ``built-in``, ``plugin <dist>`` or ``module <name>``."""
    return _SOURCES[name]


def get(name: str) -> DomainSpec:
    """The ``DomainSpec`` registered as ``name``."""
    if name not in _DOMAINS:
        raise KeyError(f"unknown domain {name!r}; registered: {names()}")
    entry = _DOMAINS[name]
    if isinstance(entry, DomainSpec):
        return entry
    module, attr = entry.split(":")
    try:
        found = vars(importlib.import_module(module))
        if attr not in found:
            raise AttributeError(f"module {module!r} has no attribute {attr!r}")
        spec = found[attr]
    except Exception as err:  # a plugin that raises while it imports hides no other domain
        raise ValueError(
            f"domain {name!r} ({_SOURCES[name]}): cannot load {entry} ({_first_line(err)})"
        ) from err
    if not isinstance(spec, DomainSpec):
        raise ValueError(f"domain {name!r} ({_SOURCES[name]}): {entry} is not a DomainSpec")
    if spec.name != name:
        raise ValueError(_misnamed(name, spec.name, _SOURCES[name]))
    return spec


def _misnamed(name: str, spec_name: str, source: str) -> str:
    """Why a domain registered under another name than its spec's is refused."""
    return (
        f"domain {name!r} ({source}) is a DomainSpec named {spec_name!r}: a checkpoint records "
        f"the spec's name, so --resume would not find it; register it as {spec_name!r} (or "
        f"name the spec {name!r})"
    )


def _same(a: str | DomainSpec, b: str | DomainSpec) -> bool:
    """Whether two entries name one domain: equal, or an import string of an imported spec."""
    return a == b or _resolves_to(a, b) or _resolves_to(b, a)


def _resolves_to(entry: str | DomainSpec, spec: str | DomainSpec) -> bool:
    if not isinstance(entry, str) or isinstance(spec, str):
        return False
    module, attr = entry.split(":")
    loaded = sys.modules.get(module)
    return loaded is not None and vars(loaded).get(attr) is spec


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return f"{type(err).__name__}: {text.splitlines()[0]}" if text else type(err).__name__


def _describe(entry: str | DomainSpec) -> str:
    return entry if isinstance(entry, str) else f"DomainSpec {entry.name!r}"
