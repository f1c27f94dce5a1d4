"""Domains by name: built in, from installed plugins, or from a module named on the CLI.

- Built-in domains (the repository's ``agents`` package) register by import string
  (``register("taxi", "agents.taxi:DOMAIN")``, imported on first use).
- A plugin is an installed package that declares its domains in the entry-point group
  ``hrl_torch.domains`` (``corridor = "hrl_corridor:DOMAIN"`` in its ``pyproject.toml``);
  ``load_plugins`` registers them.
- ``load_module("my_domains")`` imports a module and registers every ``DomainSpec`` it defines
  as ``DOMAIN`` or in ``DOMAINS`` (or that it registers itself on import). A module may register
  algorithms instead (``hrl_torch.runs.algorithms.register_algorithm``): they then run on every
  compatible domain; installed plugins declare such modules in the group ``hrl_torch.algorithms``.
"""

from __future__ import annotations

import importlib
import sys
import warnings
from importlib.metadata import entry_points

from hrl_torch.runs import algorithms
from hrl_torch.runs.domain import DomainSpec

ENTRY_POINT_GROUP = "hrl_torch.domains"
ALGORITHM_GROUP = "hrl_torch.algorithms"  # modules that register algorithms on import

_DOMAINS: dict[str, str | DomainSpec] = {}
_SOURCES: dict[str, str] = {}
_ALGORITHM_MODULES: set[str] = set()  # loaded modules that registered algorithms


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
    for ep in entry_points(group=ALGORITHM_GROUP):
        importlib.import_module(ep.value.split(":")[0])
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
    before, algorithms_before = set(_DOMAINS), set(algorithms.algorithms())
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
    if set(algorithms.algorithms()) != algorithms_before:
        _ALGORITHM_MODULES.add(module)
    if not added and not specs and module not in _ALGORITHM_MODULES:
        raise ValueError(
            f"module {module!r} defines no DOMAIN or DOMAINS (DomainSpec) and registers no "
            "algorithm"
        )
    return added


def names() -> list[str]:
    """Registered domain names."""
    return sorted(_DOMAINS)


def source(name: str) -> str:
    """Where domain ``name`` came from: ``built-in``, ``plugin <dist>`` or ``module <name>``."""
    return _SOURCES[name]


#: 0.1's names whose configuration has another name from 0.2.0 on: the dissertation's set-up
#: has the plain name, the readings made before it are ``-earlier`` variants
RENAMED_0_1 = {
    "four-agv": "four-agv-earlier",
    "four-agv-text": "four-agv",
    "two-taxi": "two-taxi-earlier",
    "two-taxi-text": "two-taxi",
    "two-taxi-text-station": "two-taxi-station",
    "taxi-fuel": "taxi-fuel-earlier",
    "taxi-fuel-text": "taxi-fuel",
}
#: ship-steering's algorithms of 0.1: ``X-text`` is ``X`` now, 0.1's ``X`` is on the variant
SHIP_ALGOS_0_1 = ("hybrid", "flat-pg", "actor-critic")
#: old names that still name today's configuration, for one minor version
DEPRECATED_NAMES = {old: new for old, new in RENAMED_0_1.items() if "-text" in old}


def recorded_names(domain: str, algo: str, version: str | None) -> tuple[str, str]:
    """Today's names of a run record's ``(domain, algo)``; 0.1's records used the old ones."""
    if version is None or not str(version).startswith("0.1"):
        return domain, algo
    if domain == "ship-steering":
        if algo.endswith("-text"):
            return domain, algo.removesuffix("-text")
        return ("ship-steering-earlier" if algo in SHIP_ALGOS_0_1 else domain), algo
    return RENAMED_0_1.get(domain, domain), algo


def current_names(domain: str, algo: str | None) -> tuple[str, str | None]:
    """``(domain, algo)`` as given by a user, with 0.1's ``-text`` names mapped (and warned)."""
    new_domain = DEPRECATED_NAMES.get(domain, domain)
    new_algo = algo
    if domain == "ship-steering" and algo is not None and algo.endswith("-text"):
        new_algo = algo.removesuffix("-text")
    if (new_domain, new_algo) != (domain, algo):
        old = f"{domain} --algo {algo}" if new_algo != algo else domain
        new = f"{new_domain} --algo {new_algo}" if new_algo != algo else new_domain
        warnings.warn(
            f"{old} is {new} since hrl-torch 0.2.0 (the dissertation's set-up has the plain "
            "name); the old name goes in 0.3.0",
            DeprecationWarning,
            stacklevel=2,
        )
    return new_domain, new_algo


def get(name: str) -> DomainSpec:
    """The ``DomainSpec`` registered as ``name`` (0.1's ``-text`` names still work, warned)."""
    if name in DEPRECATED_NAMES and name not in _DOMAINS:
        name = current_names(name, None)[0]
    if name not in _DOMAINS:
        raise KeyError(f"unknown domain {name!r}; registered: {names()}")
    entry = _DOMAINS[name]
    if isinstance(entry, DomainSpec):
        return entry.with_registered_algorithms()
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
    return spec.with_registered_algorithms()


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
