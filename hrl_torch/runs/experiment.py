"""One function that runs an experiment into a run folder, and what it builds on the way.

A domain (``hrl_torch.runs.domain.DomainSpec``, re-exported here with ``AlgoSpec`` and
``algo_family``) names its env and algorithms; ``build_trainer`` wires one algorithm up and
``run_experiment`` (what the CLI and the experiment scripts call) trains it into a run folder.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch

from hrl_torch import __version__
from hrl_torch.common.checkpoint import load_checkpoint
from hrl_torch.common.config import same
from hrl_torch.common.devices import check_device
from hrl_torch.common.rng import check_seeds
from hrl_torch.common.signals import StopOnSignal
from hrl_torch.env.envcheck import check_env
from hrl_torch.multiagent.cooperative import MultiAgentConfig
from hrl_torch.multiagent.factory import MultiAgentFactory
from hrl_torch.runs import registry
from hrl_torch.runs.domain import (  # noqa: F401 (re-exported)
    AlgoSpec,
    DomainSpec,
    EnvFactory,
    SettingError,
    algo_family,
    refused_settings,
    with_overrides,
)
from hrl_torch.runs.failures import RunFailed
from hrl_torch.runs.plots import plot_curves
from hrl_torch.runs.run_record import check_belongs, validate_run_record
from hrl_torch.runs.runlock import RunLock
from hrl_torch.runs.sizes import MAX_ROWS, check_rows, check_run_size  # noqa: F401 (MAX_ROWS re-exported)
from hrl_torch.training.runfolder import check_run_folder
from hrl_torch.training.runlog import RunLogger, code_version, hparams_of, make_run_dir, settings_of
from hrl_torch.training.trackers import check_trackers
from hrl_torch.training.trainer import TrainConfig, Trainer  # noqa: F401 (re-exported)


@dataclass
class RunOptions:
    """What the CLI lets a user change.

    Attributes:
        seeds: seeds of the learners (one learner each, run as one population).
        backend: env backend (``torch`` or, where offered, ``gymnasium``).
        envs_per_learner: ``E`` (``None``: the algorithm's default).
        steps / eval_every / eval_episodes / threshold / checkpoint_every: override the
            algorithm's ``TrainConfig`` (``None``: keep).
        out: parent folder of run folders.
        resume: checkpoint to continue from.
        progress: show a progress bar.
        tensorboard: write TensorBoard events.
        trackers: other trackers, inside the run folder: ``"csv"``, ``"wandb"`` (offline),
            ``"mlflow"`` (a SQLite store) (``hrl_torch.training.trackers``; W&B and MLflow need
            ``pip install 'hrl-torch[track]'``).
        device: torch device of envs, tables, Task-Stacks and random numbers.
        collector: train from a TorchRL ``Collector``'s frames (``hrl_torch.training.collector``).
        schedule_steps: the budget the exploration schedules are defined over (``None``: the
            run's ``steps``). A continuation beyond the original budget keeps the original's,
            so its schedules are the same functions of the absolute step.
        check_env: before anything is written, run ``hrl_torch.env.envcheck.check_env`` on a small
            env of the domain (two rows, 32 random steps; the training env is not touched).
        check_leaf_rewards: warn while training when one abstract state of a primitive sees
            different rewards (``TrainConfig.check_leaf_rewards``).
        settings: the algorithm's settings changed by name (``hrl-torch train --set``):
            ``{"learner.alpha": 0.2, "exploration.epsilon.end": 0.01}``, applied by
            ``hrl_torch.runs.domain.with_overrides``; the options above win over their names.
        cuda_graph: replay the training step as a CUDA graph on a CUDA device
            (``TrainConfig.cuda_graph``; ``--no-cuda-graph`` turns it off).
        compile_step: on the CPU, run the recorded training step compiled by inductor
            (``TrainConfig.compile_step``; ``--compile-step``).
    """

    seeds: Sequence[int] = (0,)
    backend: str = "torch"
    envs_per_learner: int | None = None
    steps: int | None = None
    eval_every: int | None = None
    eval_episodes: int | None = None
    threshold: float | None = None
    checkpoint_every: int | None = None
    out: str = "runs"
    resume: str | None = None
    progress: bool = True
    tensorboard: bool = True
    device: str = "cpu"
    collector: bool = False
    schedule_steps: int | None = None
    check_env: bool = True
    check_leaf_rewards: bool = False
    settings: dict = field(default_factory=dict)
    cuda_graph: bool = True
    compile_step: bool = False
    trackers: Sequence[str] = ()

    def __post_init__(self) -> None:
        self.seeds = check_seeds(self.seeds)
        self.trackers = check_trackers(self.trackers)
        at_least = {"envs_per_learner": 1, "steps": 1, "schedule_steps": 1, "eval_every": 0}
        at_least |= {"eval_episodes": 0, "checkpoint_every": 0}
        for name, low in at_least.items():
            value = vars(self)[name]
            if value is not None and (
                isinstance(value, bool) or not isinstance(value, int) or value < low
            ):
                raise ValueError(f"RunOptions.{name} must be an integer >= {low}, got {value!r}")
        if not str(self.out).strip():
            raise ValueError("RunOptions.out must name a folder, got an empty string")
        check_device(self.device)
        n = len(self.seeds)
        check_rows(f"{n} seeds x {self.envs_per_learner} envs per seed",
                   n * (self.envs_per_learner or 1), "use fewer envs per seed")  # fmt: skip
        check_rows(f"{n} seeds x {self.eval_episodes} evaluation episodes",
                   n * (self.eval_episodes or 0), "use fewer evaluation episodes")  # fmt: skip


#: what a checkpoint records of its run, besides the domain and algorithm
RUN_KEYS = (
    "seeds",
    "backend",
    "envs_per_learner",
    "steps",
    "schedule_steps",
    "eval_every",
    "eval_episodes",
    "threshold",
    "checkpoint_every",
    "device",
    "collector",
    "settings",
)
#: the options a continuation may change: its budget and how often it checkpoints
CONTINUE_KEYS = ("steps", "checkpoint_every")


def check_choice(domain: DomainSpec, algo: str, backend: str) -> AlgoSpec:
    """The ``AlgoSpec`` of ``algo``; a clear ``KeyError`` for an unknown algorithm or backend."""
    if algo not in domain.algos:
        raise KeyError(
            f"{domain.name!r} has no algorithm {algo!r}; choose from {sorted(domain.algos)}"
        )
    if backend not in domain.backends:
        raise KeyError(f"{domain.name!r} has no backend {backend!r}; choose from {domain.backends}")
    return domain.algos[algo]


def build_trainer(
    domain: DomainSpec, algo: str, opts: RunOptions, logger=None, *, spec: AlgoSpec | None = None
) -> Trainer:
    """Env, eval env, graph, learner and exploration of ``algo`` on ``domain``, wired up.

    ``spec``: ``algo_spec(domain, algo, opts)`` when the caller has it already (the settings
    are applied once per run). A learner or exploration that refuses a value raises
    ``SettingError`` before anything is returned.
    """
    spec = algo_spec(domain, algo, opts) if spec is None else spec
    config = _train_config(spec, opts)
    schedule_steps = opts.schedule_steps or config.steps
    seeds = list(opts.seeds)
    n_envs = opts.envs_per_learner or spec.envs_per_learner
    env = domain.make_env(seeds, n_envs, opts.backend, **spec.env_options)
    eval_env = None
    if config.eval_episodes:
        make_eval_env = domain.make_eval_env or domain.make_env
        eval_env = make_eval_env(
            [domain.eval_seed] * len(seeds), config.eval_episodes, opts.backend, **spec.env_options
        )
    graph = spec.make_graph()  # built on the CPU (building reads data), then moved
    graph.tabulate_fields(field_sizes(env))
    agents = None
    if env.n_agents is not None:  # table sets per seed and agent
        agents = MultiAgentFactory(env.n_agents, spec.multiagent or MultiAgentConfig())
    sets = len(seeds) if agents is None else agents.table_sets(len(seeds))
    learner = spec.make_learner(graph, sets).to(opts.device)
    exploration = spec.make_exploration(replace(config, steps=schedule_steps))
    graph = graph.to(opts.device)
    env = env.to(opts.device)
    eval_env = None if eval_env is None else eval_env.to(opts.device)
    evaluator = domain.make_evaluator(config) if domain.make_evaluator else None
    trainer = Trainer(
        env,
        graph,
        learner,
        exploration,
        config,
        eval_env,
        spec.executor,
        logger,
        evaluator,
        collector=opts.collector,
        agent_factory=agents,
    )
    trainer.run_config = _run_config(domain, algo, opts, config, schedule_steps, n_envs)
    return trainer


def _run_config(domain, algo, opts, config, schedule_steps: int, n_envs: int) -> dict:
    """What a checkpoint records of its run (``recorded_run`` reads it back)."""
    return {
        "domain": domain.name,
        "algo": algo,
        "seeds": list(opts.seeds),
        "backend": opts.backend,
        "envs_per_learner": n_envs,
        "steps": config.steps,
        "schedule_steps": schedule_steps,
        "eval_every": config.eval_every,
        "eval_episodes": config.eval_episodes,
        "threshold": config.threshold,
        "checkpoint_every": config.checkpoint_every,
        "device": opts.device,
        "collector": opts.collector,
        "settings": dict(opts.settings),
        "version": __version__,
        "code": code_version(),
    }


def field_sizes(env) -> dict[str, int]:
    """The discrete fields of what the agent sees in ``env`` and their sizes.

    The env's ``observation_sizes``; a multi-agent env's agent rows add its
    ``agent_observation_sizes`` and ``agent`` (``hrl_torch.env.multiagent_env.agent_rows``).
    """
    sizes = dict(getattr(env, "observation_sizes", {}))
    if getattr(env, "n_agents", None) is not None:
        sizes.update(env.agent_observation_sizes, agent=env.n_agents)
    return sizes


def algo_spec(domain: DomainSpec, algo: str, opts: RunOptions) -> AlgoSpec:
    """The ``AlgoSpec`` a run uses: ``algo``'s with ``opts.settings`` (``SettingError``)."""
    spec = check_choice(domain, algo, opts.backend)
    with refused_settings():  # (an unknown name or a value of the wrong type)
        return with_overrides(spec, opts.settings, "no setting")


def _train_config(spec: AlgoSpec, opts: RunOptions) -> TrainConfig:
    """The algorithm's ``TrainConfig`` with the options ``opts`` sets."""
    given = asdict(opts)
    changes = {
        k: given[k]
        for k in ("steps", "eval_every", "eval_episodes", "threshold", "checkpoint_every")
        if given[k] is not None
    }
    config = replace(spec.train, progress=opts.progress, cuda_graph=opts.cuda_graph, **changes)
    config.compile_step = opts.compile_step
    if opts.check_leaf_rewards:
        config.check_leaf_rewards = True
    return config


def recorded_run(run: dict) -> dict:
    """A checkpoint's run record with today's domain and algorithm names (0.1 used others)."""
    domain, algo = registry.recorded_names(run["domain"], run["algo"], run.get("version"))
    return {**run, "domain": domain, "algo": algo}


def continue_options(checkpoint: str, run: dict, **changes) -> RunOptions:
    """The ``RunOptions`` that continue the run a checkpoint records (``run``: its ``"run"``).

    ``changes`` may name the ``domain`` and ``algo`` (they must be the run's) and set any
    ``RunOptions`` field: ``steps`` and ``checkpoint_every`` to new values (a longer budget
    continues with the original schedules), the display options freely; every other option
    must equal the run's, else ``ValueError`` names it. A record that is not of its fields'
    types and ranges is refused first (``run_record.validate_run_record``: ``CheckpointError``).
    """
    validate_run_record(checkpoint, run)
    recorded = {"settings": {}} | {k: run[k] for k in ("domain", "algo", *RUN_KEYS) if k in run}
    for key, value in changes.items():
        if key in recorded and key not in CONTINUE_KEYS and not same(value, recorded[key]):
            raise ValueError(
                f"{key} {value!r} differs from the checkpoint's run ({key} {recorded[key]!r}); "
                f"a resumed run keeps its settings (only {' and '.join(CONTINUE_KEYS)} may change)"
            )
    fields = {**recorded, **changes, "resume": str(checkpoint)}
    del fields["domain"], fields["algo"]
    return RunOptions(**fields)


def check_domain_env(domain: DomainSpec, algo: str, backend: str = "torch") -> None:
    """``check_env`` on a two-row env of ``domain`` as ``algo`` builds it (``EnvContractError``).

    The torch backend is also checked for populations that equal separate runs.
    """
    spec = check_choice(domain, algo, backend)

    def make(seeds, e):
        return domain.make_env(seeds, e, backend, **spec.env_options)

    env = make([0], 2)
    graph = None if env.n_agents is not None else spec.make_graph()
    check_env(env, graph, make_env=make if backend == "torch" else None, steps=32)


def run_experiment(domain: DomainSpec, algo: str, opts: RunOptions) -> tuple[Path, dict]:
    """Train ``algo`` on ``domain`` for every seed at once; write the run folder.

    The domain's env is checked first (``check_domain_env``, unless ``opts.check_env`` is off).

    With ``opts.resume`` the run continues in the checkpoint's folder: its ``hparams.json``
    keeps the original settings and records the resume, and what was logged after the
    checkpoint (an interrupted run's last rows) is dropped before logging goes on.

    Returns the run folder and the summary written to its ``summary.json``.
    """
    torch.set_num_threads(1)
    check_choice(domain, algo, opts.backend)  # before any folder is made
    state = load_checkpoint(opts.resume) if opts.resume else None
    if state is not None and "run" in state:  # the recorded settings, checked against opts
        opts = continue_options(
            opts.resume, recorded_run(state["run"]), **_given(domain, algo, opts)
        )
    spec = algo_spec(domain, algo, opts)
    if opts.resume:  # a folder of links or of another run is refused before anything is built
        check_belongs(
            opts.resume, (state or {}).get("run", {}), check_run_folder(Path(opts.resume).parent)
        )
    check_size(domain, spec, opts)
    if opts.check_env:
        check_domain_env(domain, algo, opts.backend)
    run_dir = Path(opts.resume).parent if opts.resume else make_run_dir(opts.out, domain.name, algo)
    with RunLock(run_dir):  # one writer per folder, before anything in it changes
        return _run_locked(domain, algo, opts, spec, state, run_dir)  # (settings applied once)


def check_size(domain: DomainSpec, spec: AlgoSpec, opts: RunOptions) -> None:
    """``sizes.check_run_size`` of the run ``opts`` asks for (``SizeLimitError``)."""
    check_run_size(
        domain,
        spec,
        len(opts.seeds),
        opts.envs_per_learner or spec.envs_per_learner,
        _train_config(spec, opts).eval_episodes,
        opts.backend,
        tensorboard_writers=len(opts.seeds) if opts.tensorboard else 0,
    )


def _run_locked(domain, algo, opts: RunOptions, spec: AlgoSpec, state, run_dir: Path):
    """``run_experiment`` once the folder is this process's."""
    hparams = hparams_of(  # what this run uses: the domain's defaults with the options applied
        domain=domain.name,
        algo=algo,
        options=opts,
        train=_train_config(spec, opts),
        executor=spec.executor,
        envs_per_learner=opts.envs_per_learner or spec.envs_per_learner,
        code=code_version(),
    )
    logger, trainer = _start(domain, algo, opts, spec, run_dir, hparams, state)
    start = time.perf_counter()
    try:
        result = trainer.train(run_dir=run_dir)
    except Exception as err:
        raise _failed(err, trainer, logger, run_dir, opts) from err
    wall = time.perf_counter() - start
    with StopOnSignal() as late:  # a signal now waits: the finished run's record is written
        try:
            logger.close()
            plots = plot_curves(
                run_dir / "progress.csv",
                trainer.evaluator.metrics,
                run_dir,
                title=f"{domain.name} / {algo}",
                reference=domain.reference,
                units=trainer.evaluator.units,
            )
            summary = _summary(domain, algo, opts, trainer, result, wall, plots, run_dir)
            if late.signal is not None:
                summary["signal_after_training"] = late.signal
            logger.write_summary(summary)
        except OSError as err:  # a full disk after training: the checkpoint is the run
            raise record_unwritten(err, trainer.step, run_dir) from err
    return run_dir, summary


def record_unwritten(err: OSError, step: int, run_dir: Path) -> RunFailed:
    """A run trained to ``step`` whose plots or ``summary.json`` could not be written."""
    where = f" writing {Path(err.filename).name}" if err.filename else ""
    what = err.strerror or " ".join(str(err).split()) or type(err).__name__
    checkpoint = run_dir / "checkpoint.pt"
    kept = (
        f"its checkpoint {checkpoint} is kept (hrl-torch eval {run_dir} evaluates it)"
        if checkpoint.exists()
        else f"its logs are kept in {run_dir}"
    )
    return RunFailed(f"{what}{where} after training to step {step}; {kept}")


def _failed(err: Exception, trainer, logger, run_dir: Path, opts: RunOptions) -> RunFailed:
    """Record a run that failed while training: ``summary.json`` marked failed, or no folder.

    A fresh run that trained nothing leaves no folder; otherwise the folder stays with its last
    checkpoint (if any: ``--resume`` continues from it) and a ``summary.json`` saying why.
    """
    logger.close()
    reason = " ".join(str(err).split()) or type(err).__name__
    step, checkpoint = trainer.step, run_dir / "checkpoint.pt"
    if not opts.resume and trainer.step == 0 and not checkpoint.exists():
        shutil.rmtree(run_dir, ignore_errors=True)
        return RunFailed(f"{reason} (at step 0; the run folder was removed)")
    summary = {"status": "failed", "reason": reason, "failed_at_step": step}
    if checkpoint.exists():
        at = int(load_checkpoint(checkpoint)["trainer"]["step"])
        summary["checkpoint"] = str(checkpoint)
        left = f"continue from step {at} with: hrl-torch train --resume {checkpoint}"
    else:
        left = f"no checkpoint was written (--checkpoint-every); logs kept in {run_dir}"
    logger.write_summary(summary)
    return RunFailed(f"{reason} (at step {step}; {left})")


def _start(
    domain, algo, opts: RunOptions, spec: AlgoSpec, run_dir: Path, hparams: dict, state: dict | None
):
    """The run's logger and trainer (restored from ``state`` when resuming).

    The trainer is built and restored before anything in the folder changes, so a checkpoint
    that does not fit leaves a resumed run's folder byte for byte as it was; a failed start of
    a fresh run removes the folder ``make_run_dir`` made.
    """
    resumed_at = None if state is None else int(state["trainer"]["step"])
    logger = None
    try:
        trainer = build_trainer(domain, algo, opts, spec=spec)
        if state is not None:
            trainer.load_state_dict(state["trainer"])
        hparams = {  # the learner's and the exploration's own settings, as built
            **hparams,
            "settings": spec.settings(),  # every field, by name
            "learner": settings_of(trainer.learner),
            "exploration": settings_of(trainer.exploration),
        }
        logger = RunLogger(
            run_dir,
            opts.seeds,
            hparams,
            tensorboard=opts.tensorboard,
            resumed_at=resumed_at,
            trackers=opts.trackers,
        )
        trainer.logger = logger
    except BaseException:
        if logger is not None:  # its writers' threads stop before their folder goes
            logger.close()
        if not opts.resume:  # a failed start leaves no half-made run folder behind
            shutil.rmtree(run_dir, ignore_errors=True)
        raise
    return logger, trainer


def _summary(domain, algo, opts, trainer, result, wall: float, plots, run_dir: Path) -> dict:
    """What ``summary.json`` holds: the run's settings, status, timings and per-seed results."""
    return {
        "domain": domain.name,
        "algo": algo,
        "status": "interrupted" if result.interrupted else "finished",
        "interrupted_by": result.interrupted,
        "checkpoint": str(run_dir / "checkpoint.pt"),
        **({"partial_eval": trainer.partial_eval} if trainer.partial_eval else {}),
        "backend": opts.backend,
        "seeds": list(opts.seeds),
        "envs_per_learner": trainer.E,
        "env_steps_per_learner": result.env_steps_per_learner,
        "train_seconds": round(result.train_seconds, 3),
        "eval_seconds": round(result.eval_seconds, 3),  # the greedy evaluations' share of wall
        "wall_seconds": round(wall, 3),
        "env_steps_per_second": round(result.env_steps_per_second, 1),
        "threshold": trainer.config.threshold,
        "per_seed": [
            {
                "seed": s,
                "final_eval_return": result.final_eval[k],
                "final_eval_success": result.final_success[k],
                "final_eval_steps": result.final_steps[k] if result.final_steps else None,
                "steps_to_threshold": result.steps_to_threshold[k],
                "env_steps": result.env_steps[k],
                # all seeds train together: each seed's share of the population's time
                "wall_seconds": round(result.train_seconds, 3),
                "env_steps_per_second": round(result.env_steps_per_second / len(opts.seeds), 1),
                **trainer.evaluator.summary(k),
            }
            for k, s in enumerate(opts.seeds)
        ],
        "plots": [p.name for p in plots],
    }


#: episodes per seed ``evaluate_run`` plays for a run trained with ``eval_episodes=0``
DEFAULT_EVAL_EPISODES = 10


def evaluate_run(run_dir: str | Path, episodes: int | None = None):
    """Re-evaluate a run folder's checkpoint: ``(trainer, records)``.

    ``records`` is ``Trainer.evaluate_episodes``'s TensorDict (one greedy episode per row;
    ``None`` for continuing domains, whose evaluation is a throughput). ``episodes`` changes
    the number of evaluation episodes per seed (default: the run's, or
    ``DEFAULT_EVAL_EPISODES`` for a run trained with none). Nothing is written.
    """
    path = Path(run_dir) / "checkpoint.pt"
    hparams = check_run_folder(run_dir)  # no links, nothing of the wrong kind
    state = load_checkpoint(path)
    if "run" not in state:
        raise ValueError(f"{path} records no run configuration (written by an older hrl-torch)")
    run = recorded_run(state["run"])
    opts = continue_options(path, run, progress=False, tensorboard=False)
    check_belongs(path, state["run"], hparams)  # (both as the run wrote them)
    if episodes is not None or not opts.eval_episodes:  # a run trained without evaluation
        opts.eval_episodes = episodes or DEFAULT_EVAL_EPISODES
    domain = registry.get(run["domain"])
    spec = algo_spec(domain, run["algo"], opts)
    check_size(domain, spec, opts)
    trainer = build_trainer(domain, run["algo"], opts, spec=spec)
    load_learner(trainer, state)
    trainer.step = int(state["trainer"]["step"])
    if trainer.evaluator.continuing:  # continuing: greedy throughput per seed
        return trainer, None
    return trainer, trainer.evaluate_episodes()


def load_learner(trainer: Trainer, state: dict) -> None:
    """Restore a checkpoint's learner tables into ``trainer`` (``CheckpointError`` if unfit)."""
    from hrl_torch.common.checkpoint import CheckpointError

    try:
        trainer.learner.load_state_dict(state["trainer"]["learner"])
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        what = "; ".join(line.strip() for line in str(err).splitlines() if line.strip())
        raise CheckpointError(f"checkpoint does not fit this run: {what[:300]}") from err


def _given(domain: DomainSpec, algo: str, opts: RunOptions) -> dict:
    """``opts`` as ``continue_options`` changes: the fields set to other than their defaults.

    So ``RunOptions(resume=path)`` continues the recorded run as it was.
    """
    default = asdict(RunOptions())
    given = {k: v for k, v in asdict(opts).items() if v is not None and v != default[k]}
    given.pop("resume", None)
    if "seeds" in given:
        given["seeds"] = list(opts.seeds)
    return {"domain": domain.name, "algo": algo, **given}


def format_summary(summary: dict) -> str:
    """A short human-readable digest of a summary."""
    rows = [
        f"{summary['domain']} / {summary['algo']} ({summary['backend']}): "
        f"{len(summary['seeds'])} seeds x {summary['envs_per_learner']} envs, "
        f"{summary['env_steps_per_learner']} env steps per seed in {summary['train_seconds']} s "
        f"({summary['env_steps_per_second']:.0f} env steps/s)"
        + (f", greedy evaluation {summary['eval_seconds']} s" if "eval_seconds" in summary else "")
    ]
    for r in summary["per_seed"]:
        if "final_eval_throughput" in r:  # continuing tasks (hrl_torch.training.continuing)
            rows.append(
                f"  seed {r['seed']}: greedy throughput {r['final_eval_throughput']:.2f}, "
                f"training throughput {r.get('final_train_throughput', float('nan')):.2f} "
                f"({r['throughput_unit']})"
            )
            continue
        rows.append(
            f"  seed {r['seed']}: final eval return {r['final_eval_return']:.2f}, "
            f"success {r['final_eval_success']:.2f}, steps to threshold {r['steps_to_threshold']}"
        )
    return "\n".join(rows)


def load_summary(run_dir: str | Path) -> dict:
    """Read a run folder's ``summary.json``."""
    return json.loads((Path(run_dir) / "summary.json").read_text())
