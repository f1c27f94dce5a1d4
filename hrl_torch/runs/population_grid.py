"""A grid of configurations x seeds trained as one population, in one process, without Ray.

    hrl-torch sweep taxi --algo maxq-q --population --seeds 5
        --grid learner.alpha=0.1,0.5 --grid exploration.epsilon.end=0.01,0.05

Configuration ``c`` and seed ``k`` (of ``S``) is learner ``c * S + k`` of one population
(configuration-major). The settings that differ between configurations become per-learner
tensors (``hrl_torch.common.per_learner``: the tabular learners' ``alpha`` and ``init`` and the
exploration schedule's numbers); a seed's random streams depend on its seed alone
(``hrl_torch.common.rng``), so every (configuration, seed) equals its own separate run, table for
table. Settings every configuration shares (``steps``, ``gamma``, ...) are passed as they are.
The values reach the spec by the sweep's dotted names (``hrl_torch.runs.domain.with_overrides``).

The sweep folder ``{out}/{name}/`` holds ``sweep.json`` (the request, ``"population": true``),
``sweep.csv`` / ``sweep.md`` (the sweep's ranked table, one row per configuration; ``train s``
is the whole population's), ``per_seed.csv`` (every configuration and seed's final metrics),
``hparams.json`` (the run's options, the settings all share, and per configuration the values
that differ, as numbers) and ``checkpoint.pt`` (the population's tables; its run record holds
the per-learner values).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from hrl_torch.common.per_learner import is_per_learner
from hrl_torch.runs.domain import AlgoSpec, DomainSpec, with_overrides
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.runs.sweep import assign_ranks, seed_statistics, write_table
from hrl_torch.training.runlog import hparams_of, json_default

#: the settings that may differ between the configurations of one population (undotted
#: ``alpha`` / ``init``: the short form of ``learner.alpha`` / ``learner.init``)
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
    """``spec`` with ``values`` set by name (numbers or per-learner tensors): ``with_overrides``.

    The one place that knows how names reach the spec; ``with_overrides`` takes a tensor as
    it takes a number (the learner's and the exploration's classes check it when built).
    """
    return with_overrides(spec, values)


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
    values = population_values(configs, len(seeds))  # set by name, as train --set does
    n = len(configs) * len(seeds)
    opts = RunOptions(
        seeds=range(n),
        steps=steps,
        progress=progress,
        tensorboard=False,
        device=device,
        settings=values,
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

    Arguments as ``hrl_torch.runs.sweep.run_sweep``'s (no Ray address, no resume: a population is
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
    _write_hparams(trainer, domain.algos[algo], configs, seeds, sweep_dir)
    _write_per_seed(configs, seeds, per_learner, sweep_dir)
    rows = _ranked(configs, seeds, per_learner, metric, result.train_seconds, sweep_dir)
    write_table(rows, list(grid), metric, sweep_dir)
    return rows


def _request(domain_name, algo, grid, seeds, steps, metric):
    """The request checked before training: ``(domain, seeds, metric, request, configs)``."""
    from hrl_torch.common.rng import check_seeds
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import check_choice, check_domain_env
    from hrl_torch.runs.sweep import configurations, default_metric

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
    from hrl_torch.runs.sizes import check_run_size

    # the grid's learners x their rows, before the population's tables are built below
    base = domain.algos[algo]  # (its tables are the population's; one set of per-learner values)
    check_run_size(domain, base, n, base.envs_per_learner, base.train.eval_episodes)
    try:  # the population's own learner: a value its learner cannot take per learner is refused
        spec.make_learner(spec.make_graph(), n)
        spec.make_exploration(spec.train)
    except (TypeError, ValueError) as err:
        raise ValueError(f"--population: {err}") from None
    check_domain_env(domain, algo)
    return domain, seeds, metric, request, configs


def _ranked(configs, seeds, per_learner, metric, train_seconds, sweep_dir) -> list[dict]:
    """One finished row per configuration, the best IQM over seeds first (``sweep.rank``)."""
    s = len(seeds)
    if metric not in per_learner[0]:
        raise KeyError(f"no per-seed {metric!r}; there are {sorted(per_learner[0])}")
    rows = []
    for c, config in enumerate(configs):
        values = np.array([r[metric] for r in per_learner[c * s : (c + 1) * s]], dtype=float)
        rows.append(
            {
                "config": config,
                "metric": metric,
                "status": "finished",
                **seed_statistics(values),
                "per_seed": values.tolist(),
                "train_seconds": round(train_seconds, 3),
                "run_dir": str(sweep_dir),
            }
        )
    return assign_ranks(rows)


def population_settings(spec: AlgoSpec, values: dict, n_configs: int) -> tuple[dict, list]:
    """``(shared, per_configuration)``: the population's settings by dotted name.

    ``shared``: every field of ``with_values(spec, values)`` that is one value for all;
    ``per_configuration[c]``: the per-learner ones at configuration ``c`` as numbers (its
    first learner's entry; its seeds share it).
    """
    settings = with_values(spec, values).settings()
    shared = {k: v for k, v in settings.items() if not is_per_learner(v)}
    per = {k: v for k, v in settings.items() if is_per_learner(v)}
    n_seeds = next(iter(per.values())).shape[0] // n_configs if per else 0
    rows = [{k: v[c * n_seeds].item() for k, v in per.items()} for c in range(n_configs)]
    return shared, rows


def _write_hparams(trainer, spec: AlgoSpec, configs, seeds, sweep_dir: Path) -> None:
    """``hparams.json``: the run's options, the shared settings and each configuration's."""
    run = {k: v for k, v in trainer.run_config.items() if k != "settings"}
    shared, per_configuration = population_settings(
        spec, population_values(configs, len(seeds)), len(configs)
    )
    hparams = {
        **run,
        "seeds": list(seeds),
        "learners": "configuration c with seed seeds[k] is learner c * len(seeds) + k",
        **hparams_of(train=trainer.config),
        "settings": shared,
        "configurations": per_configuration,
    }
    text = json.dumps(hparams, indent=2, default=json_default)
    (sweep_dir / "hparams.json").write_text(text)


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
    from hrl_torch.runs.sweep import parse_grid

    for flag, given in (("--address", args.address), ("--resume", args.resume)):
        if given:
            raise ValueError(f"{flag} is for Ray sweeps; a --population sweep is one process")
    if args.in_process:
        raise ValueError("--in-process runs the trials one by one; --population runs them as one")
    if getattr(args, "logger", None):
        raise ValueError("--logger is for Ray and --in-process sweeps (a population logs no run)")
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
