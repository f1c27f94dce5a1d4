"""Experiment trackers beside TensorBoard: CSV, W&B and MLflow through ``torchrl.record.loggers``.

``--logger csv|wandb|mlflow`` (``RunOptions.trackers``) adds one tracker run per hrl-torch run,
written inside the run folder and nowhere else (no network, no home-folder files):

- ``csv``: ``torchrl``'s ``CSVLogger`` in ``RUN_DIR/csv/`` (``scalars/<tag>.csv``, one file per
  metric: the mean over seeds; ``progress.csv`` already has every seed);
- ``wandb``: ``WandbLogger`` in offline mode in ``RUN_DIR/wandb/offline-run-*/`` (its
  ``run-*.wandb`` file; ``wandb sync`` uploads it later); W&B's cache, config and data folders
  are pointed into ``RUN_DIR/wandb/`` too, and the links W&B leaves there (``latest-run``,
  ``debug.log``, ``logs/debug-core.log``) are removed at the end: a run folder holds no links;
- ``mlflow``: ``MLFlowLogger`` with a SQLite store ``RUN_DIR/mlflow.db`` and artifacts in
  ``RUN_DIR/mlartifacts/`` (``mlflow ui --backend-store-uri sqlite:///RUN_DIR/mlflow.db``);
  telemetry is off.

One tracker run per run, not per seed: MLflow's and W&B's clients hold one active run per
process. Each scalar goes as ``<tag>`` (the mean over the seeds that have a value) and, for W&B
and MLflow, ``<tag>/seed_<s>`` per seed; the run's settings (``runlog.flat_hparams``, with the
seeds) are the tracker's params / config. A resumed run opens a new tracker run named
``<run> (resumed at <step>)``; what a crashed run logged after its checkpoint stays in the
trackers (TensorBoard and the CSVs drop it). The packages are imported only when a tracker is
asked for; without them ``check_trackers`` says ``pip install 'hrl-torch[track]'``.
"""

from __future__ import annotations

import importlib.util
import math
import os
from collections.abc import Sequence
from pathlib import Path

#: trackers besides TensorBoard, and the packages each needs
TRACKERS = {"csv": (), "wandb": ("wandb",), "mlflow": ("mlflow", "sqlalchemy", "alembic")}
INSTALL = "pip install 'hrl-torch[track]'"
#: MLflow refuses longer param values
_PARAM_CHARS = 6000


def check_trackers(names: Sequence[str]) -> tuple[str, ...]:
    """``names`` as a tuple, each a known tracker whose packages are installed (``ValueError``).

    ``tensorboard`` is not one: ``RunOptions.tensorboard`` switches it.
    """
    if isinstance(names, str):
        raise ValueError(f"trackers must be a sequence of names, got the string {names!r}")
    out = []
    for name in names:
        if name not in TRACKERS:
            raise ValueError(
                f"unknown logger {name!r}: choose from tensorboard, {', '.join(TRACKERS)}"
            )
        missing = [m for m in TRACKERS[name] if importlib.util.find_spec(m) is None]
        if missing:
            raise ValueError(
                f"--logger {name} needs {', '.join(missing)}, which is not installed: {INSTALL}"
            )
        if name not in out:
            out.append(name)
    return tuple(out)


class Trackers:
    """The torchrl loggers of one run (the module docstring).

    Args:
        run_dir: the run folder (everything is written inside it).
        names: the trackers (``check_trackers``).
        seeds: the seed of each learner.
        params: the run's flat settings (``runlog.flat_hparams``).
        resumed_at: a resumed run's checkpoint step (names the new tracker run).
    """

    def __init__(
        self,
        run_dir: Path,
        names: Sequence[str],
        seeds: Sequence[int],
        params: dict,
        resumed_at: int | None = None,
    ) -> None:
        self.run_dir = Path(run_dir).resolve()
        self.seeds = list(seeds)
        resumed = "" if resumed_at is None else f" (resumed at {resumed_at})"
        self.name = self.run_dir.name + resumed
        self.loggers: dict = {}
        self._saved_env: dict = {}
        params = {k: _param(v) for k, v in {**params, "seeds": self.seeds}.items()}
        try:
            for name in check_trackers(names):
                self.loggers[name] = getattr(self, f"_open_{name}")()
                if name == "mlflow":  # (torchrl's log_hparams imports omegaconf)
                    import mlflow

                    mlflow.log_params(params)
                else:
                    self.loggers[name].log_hparams(params)
        except BaseException:
            self.close()
            raise

    def _open_csv(self):
        from torchrl.record.loggers import CSVLogger

        return CSVLogger(exp_name="csv", log_dir=str(self.run_dir))

    def _open_wandb(self):
        folder = self.run_dir / "wandb"
        self._set_env(  # before wandb is imported: it reads them once
            WANDB_MODE="offline",
            WANDB_SILENT="true",
            WANDB_DIR=str(self.run_dir),
            WANDB_CACHE_DIR=str(folder / "cache"),
            WANDB_CONFIG_DIR=str(folder / "config"),
            WANDB_DATA_DIR=str(folder / "data"),
            WANDB_ARTIFACT_DIR=str(folder / "artifacts"),
        )
        import wandb
        from torchrl.record.loggers import WandbLogger

        settings = wandb.Settings(
            console="off", silent=True, x_disable_stats=True, save_code=False, disable_git=True
        )
        return WandbLogger(
            exp_name=self.name,
            offline=True,
            save_dir=str(self.run_dir),
            project="hrl-torch",
            group=self.run_dir.name.rsplit("__", 1)[0],  # domain__algo
            log_env_packages=False,
            settings=settings,
            reinit="create_new",
        )

    def _open_mlflow(self):
        self._set_env(MLFLOW_DISABLE_TELEMETRY="true")
        import mlflow
        from torchrl.record.loggers import MLFlowLogger

        if mlflow.active_run() is not None:  # (a run of this process left open)
            mlflow.end_run()
        logger = MLFlowLogger(
            exp_name="hrl-torch",
            tracking_uri=f"sqlite:///{self.run_dir / 'mlflow.db'}",
            artifact_location=(self.run_dir / "mlartifacts").as_uri(),
        )
        mlflow.set_tag("mlflow.runName", self.name)
        return logger

    def _set_env(self, **values: str) -> None:
        """Set environment variables for the trackers' lifetime (restored by ``close``)."""
        for key, value in values.items():
            self._saved_env.setdefault(key, os.environ.get(key))
            os.environ[key] = value

    def log(self, step: int, per_seed: dict[str, Sequence[float]]) -> None:
        """Log ``{tag: [value per seed]}`` at ``step``: the seeds' mean and, but to CSV, each."""
        means, each = {}, {}
        for tag, values in per_seed.items():
            pairs = zip(self.seeds, values, strict=True)
            finite = [(s, float(v)) for s, v in pairs if math.isfinite(v)]
            if not finite:
                continue
            means[tag] = sum(v for _, v in finite) / len(finite)
            each.update({f"{tag}/seed_{s}": v for s, v in finite})
        if not means:
            return
        for name, logger in self.loggers.items():
            logger.log_metrics(means if name == "csv" else {**means, **each}, step=step)

    def close(self) -> None:
        """Finish every tracker run; restore the environment."""
        for name, logger in self.loggers.items():
            if name == "mlflow":
                import mlflow

                mlflow.end_run()
            else:
                logger.close()
            if name == "wandb":  # W&B's convenience links (latest-run, logs): unlinked
                for path in (self.run_dir / "wandb").rglob("*"):
                    if path.is_symlink():
                        path.unlink()
        self.loggers = {}
        for key, value in self._saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        self._saved_env = {}


def _param(value):
    """A param value a tracker takes: numbers, strings and flags as they are, others as text."""
    if isinstance(value, (bool, int, float, str)):
        return value[:_PARAM_CHARS] if isinstance(value, str) else value
    return str(value)[:_PARAM_CHARS]
