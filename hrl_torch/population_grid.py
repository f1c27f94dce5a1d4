"""A grid of configurations x seeds trained as one population, in one process, without Ray.

    hrl-torch sweep taxi --algo maxq-q --population --seeds 5
        --grid learner.alpha=0.1,0.5 --grid exploration.epsilon.end=0.01,0.05

Configuration ``c`` and seed ``k`` (of ``S``) is learner ``c * S + k`` of one population
(configuration-major). The settings that differ between configurations become per-learner
tensors (``hrl_torch.per_learner``: the tabular learners' ``alpha`` and ``init`` and the
exploration schedule's numbers); a seed's random streams depend on its seed alone
(``hrl_torch.rng``), so every (configuration, seed) equals its own separate run, table for
table. Settings every configuration shares (``steps``, ``gamma``, ...) are passed as they are.

The sweep folder ``{out}/{name}/`` holds ``sweep.json`` (the request, ``"population": true``),
``sweep.csv`` / ``sweep.md`` (the sweep's ranked table, one row per configuration; ``train s``
is the whole population's), ``per_seed.csv`` (every configuration and seed's final metrics)
and ``checkpoint.pt`` (the population's tables).
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from hrl_torch.experiment import AlgoSpec, DomainSpec, RunOptions, build_trainer
from hrl_torch.exploration import as_schedule
from hrl_torch.runlog import mean_ci95
from hrl_torch.sweep import with_overrides, write_table

#: the settings that may differ between the configurations of one population (undotted
#: ``alpha``: today's sweep name of the learner argument)
PER_LEARNER_NAMES = (
    "alpha",
    "learner.alpha",
    "init",
    "learner.init",
    "exploration.epsilon",
    "exploration.epsilon.start",
    "exploration.epsilon.end",
    "exploration.temperature",
    "exploration.temperature.start",
    "exploration.temperature.end",
)


# ---------------------------------------------------------------------- values
def population_values(configs: list[dict], n_seeds: int) -> dict:
    """Each name's value in the population of ``configs`` x ``n_seeds`` learners.

    A value every configuration shares stays as it is; one that differs becomes a float64
    tensor ``[C * S]``, configuration-major (configuration ``c``'s value ``S`` times). Only
    ``PER_LEARNER_NAMES`` may differ (else ``ValueError``).
    """
    values = {}
    for name in configs[0]:
        column = [config[name] for config in configs]
        if all(repr(v) == repr(column[0]) for v in column):
            values[name] = column[0]
            continue
        if name not in PER_LEARNER_NAMES:
            raise ValueError(
                f"{name} cannot differ within one population (per learner: "
                f"{', '.join(PER_LEARNER_NAMES)}); sweep it without --population"
            )
        if any(isinstance(v, bool) or not isinstance(v, int | float) for v in column):
            raise ValueError(f"{name}: a per-learner value must be a number, got {column}")
        per_row = [float(v) for v in column for _ in range(n_seeds)]
        values[name] = torch.tensor(per_row, dtype=torch.float64)
    return values


def with_values(spec: AlgoSpec, values: dict) -> AlgoSpec:
    """``spec`` with ``values`` set by name (numbers or per-learner tensors).

    The one place that knows how names reach the spec. Today ``with_overrides`` takes the
    learner's arguments by their own names (``learner.alpha`` -> ``alpha``) and knows no
    exploration, so ``exploration.*`` names wrap ``make_exploration`` here. Once
    configurations are data (dotted names in ``hrl_torch.sweep.with_overrides``), the body is
    ``return with_overrides(spec, values)``.
    """
    plain, exploration = {}, {}
    for name, value in values.items():
        head, _, rest = name.partition(".")
        if head == "exploration" and rest:
            exploration[rest] = value
        else:
            plain[rest if head == "learner" and rest else name] = value
    spec = with_overrides(spec, plain)
    if exploration:
        spec = dataclasses.replace(
            spec, make_exploration=_ExplorationWith(spec.make_exploration, exploration)
        )
    return spec


class _ExplorationWith:
    """``make_exploration`` whose schedule has some values replaced (``epsilon.end``: 0.01)."""

    def __init__(self, make_exploration, values: dict) -> None:
        self.make_exploration, self.values = make_exploration, values

    def __call__(self, config):
        exploration = copy.copy(self.make_exploration(config))
        for path, value in self.values.items():
            attr, _, field = path.partition(".")
            schedule = vars(exploration).get(attr)
            if schedule is None:
                raise ValueError(f"{type(exploration).__name__} has no exploration.{attr}")
            if not field:
                schedule = as_schedule(value)
            elif field in {f.name for f in dataclasses.fields(schedule)}:
                schedule = dataclasses.replace(schedule, **{field: value})
            else:
                raise ValueError(f"exploration.{attr} ({type(schedule).__name__}) has no {field}")
            vars(exploration)[attr] = schedule
        return exploration


# ---------------------------------------------------------------------- training
def train_grid(
    domain: DomainSpec,
    algo: str,
    configs: list[dict],
    seeds: Sequence[int],
    steps: int | None = None,
    device: str = "cpu",
    progress: bool = False,
):
    """Train ``configs`` x ``seeds`` as one population: ``(trainer, result)``.

    Learner ``c * len(seeds) + k`` is configuration ``c`` with seed ``seeds[k]``.
    """
    values = population_values(configs, len(seeds))
    spec = with_values(domain.algos[algo], values)
    domain = dataclasses.replace(domain, algos={**domain.algos, algo: spec})
    n = len(configs) * len(seeds)
    opts = RunOptions(
        seeds=range(n), steps=steps, progress=progress, tensorboard=False, device=device
    )
    # each seed repeats once per configuration: learner c * S + k runs seed k's streams
    opts.seeds = [s for _ in configs for s in seeds]
    trainer = build_trainer(domain, algo, opts)
    return trainer, trainer.train()


def per_learner_results(trainer, result) -> list[dict]:
    """Every learner's final metrics (as a run's ``summary.json`` lists them per seed)."""
    return [
        {
            "final_eval_return": result.final_eval[k],
            "final_eval_success": result.final_success[k],
            "steps_to_threshold": result.steps_to_threshold[k],
            "env_steps": result.env_steps[k],
            **trainer.evaluator.summary(k),
        }
        for k in range(len(result.final_eval))
    ]


# ---------------------------------------------------------------------- the sweep
def run_population_grid(
    domain_name: str,
    algo: str,
    grid: dict[str, list],
    seeds: int | Sequence[int],
    out: str | Path = "runs",
    steps: int | None = None,
    metric: str | None = None,
    name: str | None = None,
    device: str = "cpu",
    progress: bool = False,
) -> list[dict]:
    """``run_sweep``'s grid as one population (the module docstring); its ranked rows.

    Arguments as ``hrl_torch.sweep.run_sweep``'s (no Ray address, no resume: a population is
    one run). The sweep folder must not exist yet. Returns the rows of the ranked table
    (``status``, ``rank``, ``mean``, ``ci95``, ``per_seed`` values, ``train_seconds``).
    """
    domain, seeds, metric, request, configs = _request(
        domain_name, algo, grid, seeds, steps, metric
    )
    sweep_dir = Path(out).resolve() / (name or f"{domain_name}__{algo}__population")
    if sweep_dir.exists():
        raise ValueError(f"{sweep_dir} exists: choose another --name (a population cannot resume)")
    trainer, result = train_grid(domain, algo, configs, seeds, steps, device, progress)
    per_learner = per_learner_results(trainer, result)
    sweep_dir.mkdir(parents=True)
    (sweep_dir / "sweep.json").write_text(json.dumps({**request, "population": True}, indent=2))
    trainer.save(str(sweep_dir / "checkpoint.pt"))
    _write_per_seed(configs, seeds, per_learner, sweep_dir)
    rows = _ranked(configs, seeds, per_learner, metric, result.train_seconds, sweep_dir)
    write_table(rows, list(grid), metric, sweep_dir)
    return rows


def _request(domain_name, algo, grid, seeds, steps, metric):
    """The request checked before training: ``(domain, seeds, metric, request, configs)``."""
    from hrl_torch import registry
    from hrl_torch.experiment import check_choice, check_domain_env
    from hrl_torch.rng import check_seeds
    from hrl_torch.sweep import configurations, default_metric

    try:
        domain = registry.get(domain_name)
        check_choice(domain, algo, "torch")
    except KeyError as err:
        raise ValueError(err.args[0]) from None
    seeds = check_seeds(range(seeds) if isinstance(seeds, int) else seeds)
    if steps is not None and "steps" in grid:
        raise ValueError("steps is both swept (--grid steps=...) and fixed (--steps)")
    metric = metric or default_metric(domain)
    request = {"domain": domain_name, "algo": algo, "grid": grid, "seeds": seeds, "steps": steps}
    request = json.loads(json.dumps({**request, "metric": metric}))
    configs = configurations(grid)
    n = len(configs) * len(seeds)
    spec = with_values(domain.algos[algo], population_values(configs, len(seeds)))
    try:  # the population's own learner: a value its learner cannot take per learner is refused
        spec.make_learner(spec.make_graph(), n)
    except (TypeError, ValueError) as err:
        raise ValueError(f"--population: {err}") from None
    check_domain_env(domain, algo)
    return domain, seeds, metric, request, configs


def _ranked(configs, seeds, per_learner, metric, train_seconds, sweep_dir) -> list[dict]:
    """One finished row per configuration, the best mean over seeds first (``sweep.rank``)."""
    s = len(seeds)
    if metric not in per_learner[0]:
        raise KeyError(f"no per-seed {metric!r}; there are {sorted(per_learner[0])}")
    rows = []
    for c, config in enumerate(configs):
        values = np.array([r[metric] for r in per_learner[c * s : (c + 1) * s]], dtype=float)
        mean, half = (float(x[0]) for x in mean_ci95(values[:, None]))
        n = int(np.sum(~np.isnan(values)))
        rows.append(
            {
                "config": config,
                "metric": metric,
                "status": "finished",
                "mean": mean,
                "ci95": half if n > 1 else math.nan,
                "n_seeds": n,
                "per_seed": values.tolist(),
                "train_seconds": round(train_seconds, 3),
                "run_dir": str(sweep_dir),
            }
        )
    rows.sort(key=lambda r: (math.isnan(r["mean"]), -r["mean"] if r["mean"] == r["mean"] else 0))
    for k, row in enumerate(rows):
        row["rank"] = k + 1
    return rows


def _write_per_seed(configs, seeds, per_learner, sweep_dir: Path) -> None:
    """``per_seed.csv``: a row per (configuration, seed), its settings and final metrics."""
    keys = list(configs[0])
    metrics = list(per_learner[0])
    lines = [[*keys, "seed", *metrics]]
    for k, row in enumerate(per_learner):
        config, seed = configs[k // len(seeds)], seeds[k % len(seeds)]
        lines.append([*(config[n] for n in keys), seed, *(row[m] for m in metrics)])
    with open(sweep_dir / "per_seed.csv", "w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows(lines)


def run_population_command(args) -> int:
    """``hrl-torch sweep ... --population``: train the grid as one population, print its table."""
    from hrl_torch.sweep import parse_grid

    for flag, given in (("--address", args.address), ("--resume", args.resume)):
        if given:
            raise ValueError(f"{flag} is for Ray sweeps; a --population sweep is one process")
    name = args.name or f"{args.domain}__{args.algo}__population"
    run_population_grid(
        args.domain,
        args.algo,
        parse_grid(args.grid),
        args.seeds,
        out=args.out,
        steps=args.steps,
        name=name,
        device=args.device,
    )
    sweep_dir = Path(args.out) / name
    print((sweep_dir / "sweep.md").read_text(), end="")
    print(f"sweep folder: {sweep_dir}")
    return 0
