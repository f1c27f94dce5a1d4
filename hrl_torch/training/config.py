"""What a training run is told (``TrainConfig``) and what it returns (``TrainResult``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class TrainConfig:
    """Training options.

    Attributes:
        steps: env steps per learner to train for.
        eval_every: env steps per learner between greedy evaluations (0: only at the end).
        eval_episodes: greedy evaluation episodes per learner.
        eval_max_steps: cap on the length of an evaluation episode.
        log_every: env steps per learner between training-metric logs.
        threshold: record the first evaluation at which a learner's return reaches this.
        checkpoint_every: env steps per learner between checkpoints (0: only at the end).
        progress: show a progress bar.
        success_key: observation field that marks a successful episode end (``terminated``
            by default; e.g. ``success`` where some terminations are failures; ``"!name"``:
            the termination is a success where the field ``name`` is False).
        check_leaf_rewards: warn when one abstract state of a primitive sees different rewards
            (``hrl_torch.analysis.monitor.LeafRewardMonitor``; single-agent training only).
        cuda_graph: on a CUDA device, replay the training step as a captured CUDA graph after
            a few eager steps (``hrl_torch.training.cuda_graph``; same tables as the eager step).
        compile_step: on the CPU, record the training step after a few eager steps and run
            it compiled by inductor (``hrl_torch.training.trace_compile``; same tables; compiling
            takes tens of seconds; faster for small batches only, benchmarks/RESULTS.md).
    """

    steps: int = 50_000
    eval_every: int = 5_000
    eval_episodes: int = 100
    eval_max_steps: int = 1_000
    log_every: int = 2_000
    threshold: float | None = None
    checkpoint_every: int = 0
    progress: bool = True
    success_key: str = "terminated"
    check_leaf_rewards: bool = False
    cuda_graph: bool = True
    compile_step: bool = False

    def __post_init__(self) -> None:
        lowest = {"steps": 0, "eval_every": 0, "eval_episodes": 0, "eval_max_steps": 1}
        lowest |= {"log_every": 1, "checkpoint_every": 0}
        for name, low in lowest.items():
            value = vars(self)[name]
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"TrainConfig.{name} must be an integer >= {low}, got {value!r}")
        if self.threshold is not None and not math.isfinite(self.threshold):
            raise ValueError(f"TrainConfig.threshold must be finite, got {self.threshold!r}")


@dataclass
class TrainResult:
    """Per-learner outcome of ``Trainer.train``.

    Step counts: ``env_steps_per_learner`` (and the curve's x axis, budgets and schedules) is the
    batched clock, ``E`` per batched step; ``env_steps`` and ``steps_to_threshold`` count the
    env steps each learner really took (a row being auto-reset after an episode takes none).
    """

    final_eval: list[float]
    final_success: list[float]
    steps_to_threshold: list[int | None]
    env_steps_per_learner: int  # the schedule clock: batched steps x E

    train_seconds: float
    env_steps_per_second: float
    curve: list[tuple[int, list[float]]] = field(default_factory=list)
    final_steps: list[float] = field(default_factory=list)
    env_steps: list[int] = field(default_factory=list)  # real env steps per learner
    interrupted: str | None = None  # "SIGINT" / "SIGTERM": stopped early, checkpoint written
    eval_seconds: float = 0.0  # time spent in greedy evaluations (beside ``train_seconds``)

    @classmethod
    def of(
        cls, history, step: int, seconds: float, real_steps, interrupted, eval_seconds=0.0
    ) -> TrainResult:
        """The result of a run whose evaluations ``history`` (``EvalHistory``) recorded."""
        nan = [float("nan")] * len(history.first_hit)
        final, success, steps = nan, nan, nan
        if history.curve and history.last_success:  # the latest evaluation
            final, success = history.curve[-1][1], history.last_success
            steps = history.last_steps
        sps = float(real_steps.sum()) / max(seconds, 1e-9)
        return cls(
            final,
            success,
            list(history.first_hit),
            step,
            seconds,
            sps,
            list(history.curve),
            steps,
            [int(x) for x in real_steps],
            interrupted,
            eval_seconds,
        )
