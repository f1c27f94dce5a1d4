"""The public API: its names, their signatures, ``docs/api.md`` and the pin of the signatures.

``PUBLIC`` is the API users build on (what README.md, docs/ and examples/ import, and the
names the deprecation policy covers): module -> names. For each name the pin records
``inspect.signature`` as text (a class: its constructor's, and every public method's and
property's that hrl_torch defines on it or on an hrl_torch base class).
``tests/test_api_signatures.py`` compares the code with ``tests/api_signatures.json``, so a
changed public signature fails the fast suite until it is made on purpose:

    python scripts/api_reference.py          # writes tests/api_signatures.json and docs/api.md

(and a CHANGELOG.md line; a deprecated old form keeps working for one minor version).
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PIN = ROOT / "tests" / "api_signatures.json"
DOC = ROOT / "docs" / "api.md"

#: module -> (what it is for, its public names); ``None``: the module's ``__all__``
PUBLIC: dict[str, tuple[str, list[str] | None]] = {
    "hrl_torch": ("the top-level names (imported on first use)", None),
    "hrl_torch.hierarchy.graph": ("task graphs", ["TaskGraph", "StepContext"]),
    "hrl_torch.hierarchy.subtask": (
        "the nodes of a task graph",
        ["Subtask", "Primitive", "GraphError"],
    ),
    "hrl_torch.env.batched": ("the env contract (one batch of rows per learner)", ["BatchedEnv"]),
    "hrl_torch.env.multiagent_env": ("the multi-agent env contract", ["MultiAgentBatchedEnv"]),
    "hrl_torch.env.envcheck": ("the env contract checker", ["check_env", "EnvContractError"]),
    "hrl_torch.env.adapters": (
        "gymnasium in and out",
        ["GymnasiumBatchEnv", "BatchedToGymnasium", "stack_observations"],
    ),
    "hrl_torch.env.pettingzoo_env": (
        "PettingZoo out (a multi-agent domain as an AEC / parallel env)",
        ["MultiAgentAECEnv", "MultiAgentParallelEnv", "make_aec"],
    ),
    "hrl_torch.env.pettingzoo_in": (
        "PettingZoo in (an existing ParallelEnv / AECEnv as a multi-agent domain)",
        ["PettingZooBatchedEnv"],
    ),
    "hrl_torch.env.torchrl_env": ("TorchRL out", ["TorchRLEnv"]),
    "hrl_torch.env.torchrl_multiagent": ("TorchRL out, multi-agent", ["MultiAgentTorchRLEnv"]),
    "hrl_torch.execution.executor": (
        "the batched Task-Stack executor",
        ["HierarchicalExecutor", "ExecutorConfig", "SubtaskTimeoutError", "BadStepError"],
    ),
    "hrl_torch.modules.exploration": (
        "exploration policies",
        ["Greedy", "EpsilonGreedy", "Boltzmann", "TriggeredEpsilon", "linear_epsilon"],
    ),
    "hrl_torch.modules.schedules": (
        "schedules of step sizes and exploration rates",
        ["Constant", "Linear", "Exponential", "VisitCount"],
    ),
    "hrl_torch.modules.tiles": ("tile coding", ["TileCoder"]),
    "hrl_torch.modules.policies": (
        "policy heads of the policy-gradient learners",
        ["SoftmaxPolicyHead", "TileGaussianPolicyHead"],
    ),
    "hrl_torch.learners": ("the learners", None),
    "hrl_torch.analysis": ("exact analysis of small models (optima, abstractions)", None),
    "hrl_torch.training.trainer": ("the training loop", ["Trainer"]),
    "hrl_torch.training.config": ("its settings and result", ["TrainConfig", "TrainResult"]),
    "hrl_torch.multiagent.cooperative": (
        "multi-agent HRL (Chapter 6)",
        [
            "MultiAgentConfig",
            "Cooperation",
            "Communication",
            "CooperativeSubtask",
            "cooperative_graph",
        ],
    ),
    "hrl_torch.multiagent.factory": ("the multi-agent agent factory", ["MultiAgentFactory"]),
    "hrl_torch.common.config": ("settings as data", ["Make", "Budget"]),
    "hrl_torch.common.devices": ("devices", ["constant_on"]),
    "hrl_torch.runs.domain": (
        "domains and algorithms as data",
        ["DomainSpec", "AlgoSpec", "algo_family", "setting_names", "with_overrides"],
    ),
    "hrl_torch.runs.registry": (
        "the domain registry",
        ["register", "get", "names", "source", "load_module"],
    ),
    "hrl_torch.runs.experiment": (
        "runs as the CLI makes them",
        [
            "RunOptions",
            "build_trainer",
            "run_experiment",
            "evaluate_run",
            "load_summary",
            "format_summary",
        ],
    ),
    "hrl_torch.runs.sweep": ("sweeps", ["parse_grid", "run_sweep"]),
    "hrl_torch.runs.report": ("comparisons of runs", ["compare_plot", "summary_row"]),
    "hrl_torch.runs.plots": ("curves and their statistics", ["iqm", "iqm_interval", "plot_curves"]),
    "hrl_torch.common.stats": (
        "the one estimator: IQM and rliable's stratified-bootstrap interval",
        ["iqm", "bootstrap_interval", "aggregate_iqm", "aggregate_mean", "optimality_gap"],
    ),
    "hrl_torch.training.trackers": (
        "CSV, W&B and MLflow trackers (train --logger)",
        ["Trackers", "check_trackers"],
    ),
}


def names_of(module: str) -> list[str]:
    """The public names of ``module`` (``PUBLIC``, or its ``__all__``)."""
    names = PUBLIC[module][1]
    return list(names) if names is not None else list(importlib.import_module(module).__all__)


def _text(sig: inspect.Signature) -> str:
    return re.sub(r" at 0x[0-9a-f]+", "", str(sig))  # (a default's repr without its address)


def _ours(obj) -> bool:
    return (getattr(obj, "__module__", None) or "").split(".")[0] == "hrl_torch"


def _signature(obj) -> str:
    try:
        return _text(inspect.signature(obj))
    except (TypeError, ValueError):  # (a builtin without one)
        return "(...)"


def members(cls: type) -> dict[str, str]:
    """``cls``'s public methods and properties that hrl_torch defines, with their signatures."""
    out = {}
    for owner in reversed([c for c in cls.__mro__ if _ours(c)]):  # (the subclass's last)
        for name, value in vars(owner).items():
            if name.startswith("_"):
                continue
            if isinstance(value, property):
                out[name] = "property"
            elif isinstance(value, (staticmethod, classmethod)):
                out[name] = _signature(value.__func__)
            elif inspect.isfunction(value):
                out[name] = _signature(value)
    return dict(sorted(out.items()))


def signatures() -> dict[str, str]:
    """``module.name`` (and ``module.Class.method``) -> its signature, for all of ``PUBLIC``."""
    out = {}
    for module in PUBLIC:
        mod = importlib.import_module(module)
        for name in names_of(module):
            obj = getattr(mod, name)
            key = f"{module}.{name}"
            out[key] = _signature(obj)
            if inspect.isclass(obj):
                out.update({f"{key}.{m}": s for m, s in members(obj).items()})
    return out


def _summary(obj) -> str:
    doc = inspect.getdoc(obj) or ""
    return doc.split("\n\n")[0].replace("\n", " ").strip()


def markdown() -> str:
    """``docs/api.md``: every public name with its signature and its docstring's first line."""
    lines = [
        "# API reference",
        "",
        "The public API of hrl-torch: the names below, importable from the module each section",
        "names. Anything else (a name starting with `_`, a module not listed, `agents/` and",
        "`envs/`, the built-in domains) may change without notice. A change to a name here",
        "follows the README's deprecation policy: the old form keeps working for one minor",
        "version with a `DeprecationWarning` naming its replacement, and CHANGELOG.md lists it.",
        "`tests/test_api_signatures.py` pins every signature below (and every public method's)",
        "in `tests/api_signatures.json`, so a change fails the fast suite until it is made on",
        "purpose: `python scripts/api_reference.py` rewrites the pin and this page.",
        "",
    ]
    for module, (what, _) in PUBLIC.items():
        mod = importlib.import_module(module)
        lines += [f"## `{module}`: {what}", ""]
        for name in names_of(module):
            obj = getattr(mod, name)
            kind = "class" if inspect.isclass(obj) else "function" if callable(obj) else "value"
            sig = _signature(obj) if callable(obj) else ""
            lines.append(f"- `{name}{sig}` ({kind}): {_summary(obj)}")
            if inspect.isclass(obj):
                methods = [m for m in members(obj)]
                if methods:
                    lines.append(
                        f"  Methods and properties: {', '.join(f'`{m}`' for m in methods)}."
                    )
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.parse_args()
    PIN.write_text(json.dumps(signatures(), indent=1, sort_keys=True) + "\n")
    DOC.write_text(markdown())
    pin, doc = PIN.relative_to(ROOT), DOC.relative_to(ROOT)
    print(f"wrote {pin} ({len(signatures())} signatures) and {doc}")


if __name__ == "__main__":
    main()
