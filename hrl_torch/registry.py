"""Domains by name, registered lazily by import string (``"agents.taxi:DOMAIN"``)."""

from __future__ import annotations

import importlib

from hrl_torch.experiment import DomainSpec

_DOMAINS: dict[str, str] = {}


def register(name: str, entry: str) -> None:
    """Register domain ``name`` as ``"module:attribute"`` (imported on first use)."""
    if ":" not in entry:
        raise ValueError(f"entry must look like 'module:attribute', got {entry!r}")
    _DOMAINS[name] = entry


def names() -> list[str]:
    """Registered domain names."""
    return sorted(_DOMAINS)


def get(name: str) -> DomainSpec:
    """The ``DomainSpec`` registered as ``name``."""
    if name not in _DOMAINS:
        raise KeyError(f"unknown domain {name!r}; registered: {names()}")
    module, attr = _DOMAINS[name].split(":")
    return getattr(importlib.import_module(module), attr)
