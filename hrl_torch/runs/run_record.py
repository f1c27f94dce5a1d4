"""A checkpoint's run record, checked field by field, and checked to belong to its folder.

A checkpoint records its run (``Trainer.run_config``: domain, algorithm, seeds, sizes, device,
settings). A resume or an evaluation rebuilds the run from that record, so a record edited or
damaged (``envs_per_learner='abc'``, ``device='cuda:7'``, ``eval_episodes=10**9``) is refused
here, in one line naming the field, before anything is built. ``check_belongs`` refuses a
checkpoint that is another run's (a taxi ``q`` checkpoint copied into a taxi ``maxq-q`` folder
would mix two algorithms' logs): the folder's ``hparams.json`` names its run.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from hrl_torch.common.checkpoint import CheckpointError
from hrl_torch.common.devices import check_device
from hrl_torch.common.limits import SizeLimitError
from hrl_torch.runs.sizes import check_rows


def _whole(low: int, optional: bool = False):
    def check(value) -> str | None:
        if value is None and optional:
            return None
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            return f"a whole number >= {low}" + (" or null" if optional else "")
        return None

    return check


def _kind(kind: type, what: str):
    return lambda value: None if isinstance(value, kind) else what


def _seeds(value) -> str | None:
    ok = (
        isinstance(value, list | tuple)
        and value
        and all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32 for s in value)
    )
    return None if ok else "a non-empty list of seeds in [0, 2**32)"


def _threshold(value) -> str | None:
    if value is None or (
        isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    ):
        return None
    return "a finite number or null"


def _device(value) -> str | None:
    try:
        check_device(value)
    except ValueError as err:
        return f"a device this machine has ({err})"
    return None


#: each recorded field and what it must be (a field an older record lacks is not checked)
FIELDS = {
    "domain": _kind(str, "a domain name"),
    "algo": _kind(str, "an algorithm name"),
    "seeds": _seeds,
    "backend": _kind(str, "a backend name"),
    "envs_per_learner": _whole(1),
    "steps": _whole(1),
    "schedule_steps": _whole(1, optional=True),
    "eval_every": _whole(0),
    "eval_episodes": _whole(0),
    "threshold": _threshold,
    "checkpoint_every": _whole(0),
    "device": _device,
    "collector": _kind(bool, "true or false"),
    "settings": _kind(dict, "an object of settings by name"),
}


def validate_run_record(path, run) -> dict:
    """``run`` (a checkpoint's ``"run"``) if every field is of its type and range.

    Raises:
        CheckpointError: ``'{path}: its run record's envs_per_learner is 'abc', expected a
            whole number >= 1 (the checkpoint was edited or damaged)'``.
    """
    if not isinstance(run, dict):
        raise CheckpointError(f"{path}: its run record is a {type(run).__name__}, not an object")
    for key in ("domain", "algo"):
        if key not in run:
            raise CheckpointError(f"{path}: its run record names no {key}")
    for key, check in FIELDS.items():
        if key in run:
            expected = check(run[key])
            if expected is not None:
                shown = repr(run[key])
                shown = shown if len(shown) <= 40 else shown[:37] + "..."
                raise CheckpointError(
                    f"{path}: its run record's {key} is {shown}, expected {expected} (the "
                    "checkpoint was edited or damaged)"
                )
    seeds = len(run.get("seeds", ()))
    for key in ("envs_per_learner", "eval_episodes"):
        try:
            check_rows(f"{seeds} seeds x {run.get(key, 0)} {key}", seeds * run.get(key, 0),
                       "the checkpoint was edited or damaged")  # fmt: skip
        except SizeLimitError as err:
            raise CheckpointError(f"{path}: its run record asks for {err}") from None
    return run


def _canonical(value) -> str:
    from hrl_torch.training.runlog import json_default

    return json.dumps(json.loads(json.dumps(value, default=json_default)), sort_keys=True)


def check_belongs(checkpoint: str | Path, run: dict, hparams: dict | None) -> None:
    """Refuse a checkpoint whose run is not the one its folder's ``hparams.json`` records.

    Domain, algorithm, seeds and the settings changed by name (``--set``) must agree.
    """
    if hparams is None:
        return
    folder = Path(checkpoint).parent / "hparams.json"
    recorded = {
        "domain": hparams.get("domain"),
        "algo": hparams.get("algo"),
        "seeds": hparams.get("options.seeds"),
        "settings": hparams.get("options.settings"),
    }
    for key, theirs in recorded.items():
        if theirs is None or key not in run:
            continue
        if _canonical(run[key]) != _canonical(theirs):
            raise CheckpointError(
                f"checkpoint does not fit this run: {checkpoint} is a checkpoint of another run "
                f"than its folder's ({key} "
                f"{_canonical(run[key])[:40]}, {folder} records {_canonical(theirs)[:40]}): a "
                "checkpoint continues only its own run; put it back in its own run folder"
            )
