"""A run's size checked against this machine before anything of it is built.

The CLI's options, a checkpoint's run record and a population grid all reach
``check_run_size`` before the trainer exists, so an oversized request is one line (a
``SizeLimitError``: a ``ValueError``) instead of the out-of-memory killer. The run's memory is
estimated from its parts, measured on tiny instances: the env's bytes per row (an env of 2
and of 4 rows), a learner's table bytes (a learner of one table set), and ``ROW_BYTES`` for
what each row adds beyond its env (the Task-Stack, transitions, exploration draws).
"""

from __future__ import annotations

from hrl_torch.common.limits import check_bytes, check_threads, gib, tensor_bytes

#: bytes each env row takes beyond the env's own tensors (measured: taxi maxq-q grew by
#: 3.0 KB of resident memory per row at 32,768 rows, 4.7 KB at 4,096)
ROW_BYTES = 3072
#: the most env rows (seeds x envs per seed, and seeds x evaluation episodes) a run may ask for
MAX_ROWS = 2**24


def check_rows(what: str, rows: int, advice: str) -> None:
    """Refuse more than ``MAX_ROWS`` rows (``SizeLimitError``), before any estimate."""
    from hrl_torch.common.limits import SizeLimitError

    if rows > MAX_ROWS:
        raise SizeLimitError(
            f"{what} = {rows:,} env rows, more than {MAX_ROWS:,} (each row keeps kilobytes "
            f"of state: this machine would run out of memory); {advice}"
        )


def check_run_size(
    domain,
    spec,
    learners: int,
    envs_per_learner: int,
    eval_episodes: int,
    backend: str = "torch",
    tensorboard_writers: int = 0,
) -> None:
    """Refuse a run of ``learners`` x ``envs_per_learner`` rows this machine cannot hold.

    Args:
        domain: the run's ``DomainSpec``.
        spec: its ``AlgoSpec``, the run's settings applied.
        learners: learners of the population (seeds; configurations x seeds of a grid).
        envs_per_learner: ``E``.
        eval_episodes: evaluation rows per learner.
        backend: the env backend.
        tensorboard_writers: TensorBoard writers the run opens (one thread each).

    Raises:
        SizeLimitError: naming the request, its estimate and the machine's budget.
    """
    for value, name in ((envs_per_learner, "envs per learner"), (eval_episodes, "eval episodes")):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"{name} must be a whole number >= 0, got {value!r}")
    check_rows(f"{learners} seeds x {envs_per_learner} envs per seed", learners * envs_per_learner,
               "use fewer envs per seed")  # fmt: skip
    check_rows(f"{learners} seeds x {eval_episodes} evaluation episodes",
               learners * eval_episodes, "use fewer evaluation episodes")  # fmt: skip
    if tensorboard_writers:
        check_threads(
            f"{tensorboard_writers:,} seeds' TensorBoard writers", tensorboard_writers,
            "use fewer seeds or --no-tensorboard",
        )  # fmt: skip
    small = [domain.make_env([0], e, backend, **spec.env_options) for e in (2, 4)]
    per_row = ROW_BYTES + max(0, tensor_bytes(small[1]) - tensor_bytes(small[0])) / 2
    agents = getattr(small[0], "n_agents", None) or 1
    rows = learners * (envs_per_learner + eval_episodes)
    check_bytes(
        f"{learners:,} seeds x ({envs_per_learner:,} envs + {eval_episodes:,} evaluation "
        f"episodes) = {rows:,} env rows at about {per_row / 1024:.1f} KiB each",
        rows * per_row,
        "use fewer seeds, envs per seed or evaluation episodes",
    )
    per_learner = tensor_bytes(spec.make_learner(spec.make_graph(), 1)) * agents
    check_bytes(
        f"{learners:,} learners' tables ({gib(per_learner)} each) and {rows:,} env rows",
        learners * per_learner + rows * per_row,
        "use fewer seeds (or configurations)",
    )
