"""The module paths of hrl-torch 0.1, kept importable for one minor version.

0.2.0 put the flat modules of ``hrl_torch/`` into subpackages by layer (docs/design.md).
``import hrl_torch.trainer`` still works: a finder on ``sys.meta_path`` answers the old name with
the module at its new place (the same object, so patching it patches the real one) and a
``DeprecationWarning`` naming the new path. The three old modules whose names are packages now
(``env``, ``training``, ``multiagent``) answer their old names from the package instead
(``moved_attribute``). Removed in 0.3.0.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

REMOVED_IN = "0.3.0"

#: old module under hrl_torch -> its path under hrl_torch since 0.2.0
MOVED: dict[str, str] = {
    "adapters": "env.adapters",
    "agent": "training.agent",
    "argtypes": "runs.argtypes",
    "broadcast": "multiagent.broadcast",
    "checkpoint": "common.checkpoint",
    "cli": "runs.cli",
    "cli_parser": "runs.cli_parser",
    "collector": "training.collector",
    "communication": "multiagent.communication",
    "config": "common.config",
    "continuing": "training.continuing",
    "cuda_graph": "training.cuda_graph",
    "deferred": "training.deferred",
    "descent": "execution.descent",
    "devicecheck": "runs.devicecheck",
    "devices": "common.devices",
    "domain": "runs.domain",
    "env": "env.batched",
    "envcheck": "env.envcheck",
    "eval_plan": "modules.eval_plan",
    "evaluation": "training.evaluation",
    "executor": "execution.executor",
    "experiment": "runs.experiment",
    "exploration": "modules.exploration",
    "failures": "runs.failures",
    "graph": "hierarchy.graph",
    "graph_compile": "hierarchy.graph_compile",
    "heads": "modules.heads",
    "hybrid": "learners.hybrid",
    "metrics": "training.metrics",
    "monitor": "analysis.monitor",
    "multiagent": "multiagent.cooperative",
    "multiagent_env": "env.multiagent_env",
    "multiagent_factory": "multiagent.factory",
    "ops": "common.ops",
    "per_learner": "common.per_learner",
    "pettingzoo_env": "env.pettingzoo_env",
    "plots": "runs.plots",
    "policies": "modules.policies",
    "population_grid": "runs.population_grid",
    "progress": "learners.progress",
    "registry": "runs.registry",
    "report": "runs.report",
    "rng": "common.rng",
    "runlock": "runs.runlock",
    "runlog": "training.runlog",
    "signals": "common.signals",
    "sparse_store": "common.sparse_store",
    "stack": "execution.stack",
    "steps": "training.steps",
    "subtask": "hierarchy.subtask",
    "sweep": "runs.sweep",
    "sync_count": "common.sync_count",
    "tables": "modules.tables",
    "threads": "common.threads",
    "tiles": "modules.tiles",
    "torchrl_env": "env.torchrl_env",
    "torchrl_multiagent": "env.torchrl_multiagent",
    "trace_compile": "training.trace_compile",
    "trainer": "training.trainer",
    "training": "training.config",
    "transitions": "execution.transitions",
    "validate": "learners.validate",
}

#: old modules whose name is now a package: the package answers their names
NOW_PACKAGES = {
    "env": "env.batched",
    "training": "training.config",
    "multiagent": "multiagent.cooperative",
}


def warn_moved(old: str, new: str, stacklevel: int = 3) -> None:
    """One DeprecationWarning saying where old lives now."""
    warnings.warn(
        f"{old} moved to {new} in hrl-torch 0.2.0; the old path goes in {REMOVED_IN}",
        DeprecationWarning,
        stacklevel=stacklevel,
    )


class _MovedLoader(importlib.abc.Loader):
    """Loads an old module name as the module at its new path (no new module object)."""

    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec):
        warn_moved(spec.name, self.new, stacklevel=3)  # past importlib's frames
        return importlib.import_module(self.new)

    def exec_module(self, module) -> None:
        """Nothing to run: the module at the new path is already executed."""


class MovedModuleFinder(importlib.abc.MetaPathFinder):
    """Finds hrl_torch.<old> for every moved module that is not a package now."""

    def find_spec(self, fullname, path=None, target=None):
        """A spec loading the new module for an old name, else None."""
        prefix, _, old = fullname.partition(".")
        if prefix != "hrl_torch" or old not in MOVED or old in NOW_PACKAGES:
            return None
        return importlib.util.spec_from_loader(fullname, _MovedLoader("hrl_torch." + MOVED[old]))


def install() -> None:
    """Put the finder on sys.meta_path once."""
    if not any(isinstance(f, MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.append(MovedModuleFinder())


def moved_attribute(package: str, name: str):
    """package.name for an old module that is a package now, with its warning.

    Raises:
        AttributeError: name was not in the old module either.
    """
    old = package.partition(".")[2]
    new = "hrl_torch." + NOW_PACKAGES[old]
    module = importlib.import_module(new)
    if name.startswith("__") or not hasattr(module, name):
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    warn_moved(f"{package}.{name}", f"{new}.{name}", stacklevel=4)
    value = getattr(module, name)
    setattr(sys.modules[package], name, value)
    return value


def trainer_agent_factory(agent_factory, multiagent, env):
    """0.1's ``Trainer(..., multiagent=config)`` as today's ``agent_factory``, with its warning.

    The one place below ``hrl_torch.multiagent`` that names it, by import string: a shim that
    goes with 0.1's form in 0.3.0.
    """
    if multiagent is None:
        return agent_factory
    if agent_factory is not None:
        raise TypeError("Trainer takes agent_factory= or 0.1's multiagent=, not both")
    warnings.warn(
        "Trainer(multiagent=config) is 0.1's: pass agent_factory=MultiAgentFactory(env.n_agents, "
        f"config) (hrl_torch.multiagent.factory); 0.1's form goes in {REMOVED_IN}",
        DeprecationWarning,
        stacklevel=3,
    )
    factory = importlib.import_module("hrl_torch.multiagent.factory").MultiAgentFactory
    return factory(env.n_agents, multiagent)
