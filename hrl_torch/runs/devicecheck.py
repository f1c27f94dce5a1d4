"""``check_any_device``: does a run keep the any-device rules? No GPU needed.

A run that works on the CPU can fail, or crawl, on a GPU: a table made on the CPU that a step
indexes with device tensors, ``TABLE.to(device)`` inside a step (a synchronising copy that a
CUDA-graph capture refuses), ``.item()`` or ``if tensor:`` in a step (each waits for the GPU).
``check_any_device(build)`` looks for them in four passes and names, for each finding, the
file and line of the code that made it (your env's, your subtask's, or this project's):

1. the CPU with the rules a GPU run gets (static shapes, every broadcast round): every host
   read and data-dependent op of ``steps`` training steps (``sync_count.HostSyncCounter``);
2. ``meta`` (CUDA's device rules, no data): the run builds and takes ``steps`` eager steps
   (a tensor left on the CPU or a value read back raises), copying nothing from the host;
3. ``meta`` again, a fresh run, when pass 2 found nothing (what it finds, a capture refuses
   too): the step recorded and replayed with a CUDA graph's rules (``cuda_graph.StepGraph``,
   backend ``"trace"``), which also refuses a step whose Python integers move unevenly.
4. pass 1's run, once trained, in one greedy evaluation (at most ``EVAL_STEPS`` steps) if it
   has an eval env: places that read the device more often than every
   ``evaluation.READ_EVERY`` steps (an evaluation reads by design only that often).

``build(device)`` returns the ``Trainer`` on ``device``, built on the CPU and then moved (what
``experiment.build_trainer`` does with ``RunOptions.device``). ``hrl-torch check`` runs this on
a registered domain (docs/your-own-hierarchy.md, "Will it run on a GPU?").
"""

from __future__ import annotations

import dataclasses
import traceback
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from hrl_torch.common import devices
from hrl_torch.common.sync_count import HostSyncCounter, place
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.multiagent import broadcast
from hrl_torch.training.cuda_graph import StepGraph
from hrl_torch.training.evaluation import READ_EVERY

__all__ = [
    "DeviceReport",
    "DeviceRuleError",
    "check_any_device",
    "check_domain",
    "counting_steps",
    "off_cpu_rules",
]

_READ = (
    "a value read back to the host (.item(), bool(), int(), float(), `if tensor:`, tolist): "
    "a GPU step waits here; keep it a tensor (torch.where) or read it at a log interval"
)
_SHAPE = (
    "an op whose output size depends on the data (nonzero, masked_select, x[mask], unique, "
    "repeat_interleave without output_size): it reads the device; use masks and torch.where"
)
#: what each kind of op counted by ``HostSyncCounter`` means, and what to do instead
HINTS = {
    "item": _READ,
    "tolist": _READ,
    "numpy": _READ,
    "to_host": "a copy back to the CPU (.cpu(), .to('cpu')): " + _READ.split(": ", 1)[1],
    "nonzero": _SHAPE,
    "masked_select": _SHAPE,
    "bool-index": _SHAPE,
    "unique": _SHAPE,
    "repeat_interleave": _SHAPE,
    "to_device": (
        "a copy of host data to the device inside the step (TABLE.to(device), "
        "torch.tensor(data, device=...), a device tensor indexed with CPU indices): it "
        "synchronises and a CUDA-graph capture refuses it; read module-level tables through "
        "hrl_torch.common.devices.constant_on, make new tensors with device= of the step's inputs"
    ),
}


class DeviceRuleError(RuntimeError):
    """A run that breaks the any-device rules; ``findings``: one line per place and pass."""

    def __init__(self, findings: list[str]) -> None:
        self.findings = list(findings)
        lines = "\n".join(f"  - {f}" for f in self.findings)
        n = len(self.findings)
        super().__init__(f"the run breaks the any-device rules: {n} finding(s):\n{lines}")


@dataclass
class DeviceReport:
    """What ``check_any_device`` found: one line per place and pass (empty: every rule kept).

    (A place can appear twice: a ``.item()`` is counted on the CPU and raises on ``meta``.)
    """

    findings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """No finding."""
        return not self.findings

    def raise_if_any(self) -> None:
        """``DeviceRuleError`` listing the findings, if there are any."""
        if self.findings:
            raise DeviceRuleError(self.findings)


def check_any_device(build: Callable[[str], object], steps: int = 70) -> DeviceReport:
    """The passes of the module docstring (``steps`` training steps each, then an evaluation).

    ``steps``: 70 by default, past the first refill of the random blocks (64 steps).
    """
    with off_cpu_rules():  # (passes 1 and 4: one run on the CPU, trained, then evaluated)
        findings, trained = _reads_on_cpu(build, steps)
        evaluation = [] if trained is None else _evaluation_reads(trained)
    on_meta, stepped = _steps_on_meta(build, steps)
    findings += on_meta
    if stepped and not on_meta:  # (what the eager passes find, a capture refuses too)
        findings += _replay_on_meta(build)
    return DeviceReport(findings + evaluation)


@contextmanager
def off_cpu_rules() -> Iterator[None]:
    """The CPU with the shape rules a GPU run gets (``devices.STATIC_SHAPES`` and friends)."""
    saved = devices.STATIC_SHAPES, broadcast.STATIC_ROUNDS
    devices.STATIC_SHAPES = broadcast.STATIC_ROUNDS = True
    try:
        yield
    finally:
        devices.STATIC_SHAPES, broadcast.STATIC_ROUNDS = saved


def _counted(counter, steps: int, where: str) -> list[str]:
    """One finding per (kind, place) the counter saw (``counter``: its ``where``, or itself)."""
    out = []
    for key, n in getattr(counter, "where", counter).items():
        kind, at = key.split(" ", 1)
        out.append(f"{at}: {HINTS.get(kind, kind)} [{kind}, {n} in {steps} steps {where}]")
    return out


def _failure(err: Exception, doing: str) -> str:
    """A finding for an exception: where it was raised (outside torch) and what it says."""
    at = place(traceback.extract_tb(err.__traceback__))
    text = f"{type(err).__name__}: {err}".splitlines()[0]
    if isinstance(err, (GraphError, ValueError)):  # (names the subtask or env, and the fix)
        return f"{at}: {doing} failed: {text}"
    if "meta" in text and any(w in text for w in ("item", "data", "copy out")):
        hint = _READ
    elif "device" in text:
        hint = "a tensor made or kept on the CPU meets the run's device: " + HINTS["to_device"]
    else:
        hint = "see the error"
    return f"{at}: {doing} failed: {text} ({hint})"


def _steps(trainer, steps: int, counter: HostSyncCounter) -> None:
    for _ in range(3):  # (first uses fill caches: constant tables, random blocks)
        trainer.train_step()
    with counter:
        for _ in range(steps):
            trainer.train_step()


def _reads_on_cpu(build, steps: int) -> tuple[list[str], object]:
    """The findings of ``steps`` steps on the CPU (under ``off_cpu_rules``), and the trainer.

    The trainer is ``None`` if building it or a step failed.
    """
    counter = HostSyncCounter(stacks=True)
    try:
        trainer = build("cpu")
    except Exception as err:  # noqa: BLE001  (reported as a finding)
        return [_failure(err, "building the run on the CPU")], None
    try:
        _steps(trainer, steps, counter)
    except Exception as err:  # noqa: BLE001
        return [_failure(err, "a training step on the CPU with a GPU's shape rules")], None
    return _counted(counter, steps, "on the CPU"), trainer


def _steps_on_meta(build, steps: int) -> tuple[list[str], bool]:
    """The findings of ``steps`` eager steps on ``meta``, and whether the steps ran."""
    try:
        trainer = build("meta")
    except Exception as err:  # noqa: BLE001
        return [_failure(err, "building the run for a device other than the CPU ('meta')")], False
    counter = HostSyncCounter(stacks=True)
    try:
        _steps(trainer, steps, counter)
    except Exception as err:  # noqa: BLE001
        return [_failure(err, "a training step on 'meta' (CUDA's device rules)")], False
    return _counted(counter, steps, "on 'meta'"), True


#: evaluation steps the evaluation pass plays at most (its episodes or window are cut to it)
EVAL_STEPS = 200


def _evaluation_reads(trainer) -> list[str]:
    """Places reading at (nearly) every step of ``trainer``'s greedy evaluation.

    Run under ``off_cpu_rules``. An evaluation reads by design, every
    ``evaluation.READ_EVERY`` steps off the CPU; a place that reads more often than that (an
    env's or a subtask's own read) is a finding.
    """
    if trainer.eval_env is None:  # (the run evaluates nothing)
        return []
    counter = HostSyncCounter(stacks=True)
    try:
        _shorten_evaluation(trainer)
        with counting_steps(type(trainer.eval_env)) as played, counter:
            trainer.evaluate()
    except Exception as err:  # noqa: BLE001
        return [_failure(err, "a greedy evaluation on the CPU with a GPU's shape rules")]
    limit = played[0] / READ_EVERY + 2
    per_step = Counter({k: n for k, n in counter.where.items() if n > limit})
    return _counted(per_step, played[0], "of a greedy evaluation")


def _shorten_evaluation(trainer) -> None:
    """At most ``EVAL_STEPS`` steps: episodes capped, a throughput window cut."""
    trainer.config.eval_max_steps = min(trainer.config.eval_max_steps, EVAL_STEPS)
    ev = trainer.evaluator
    if dataclasses.is_dataclass(ev) and {"horizon", "max_steps"} <= set(vars(ev)):
        window = {"burn_in": 0, "horizon": EVAL_STEPS, "max_steps": EVAL_STEPS}
        trainer.evaluator = dataclasses.replace(
            ev, **{k: v for k, v in window.items() if k in vars(ev)}
        )


@contextmanager
def counting_steps(env_class) -> Iterator[list[int]]:
    """``[n]``: the steps of every ``env_class`` env taken in the block.

    The class's ``step`` is wrapped, not one instance's, so envs split off by ``env.subset``
    (a copy of the instance) count too and step themselves.
    """
    played = [0]
    own = vars(env_class).get("step")
    step = env_class.step

    def counted(env, action):
        played[0] += 1
        return step(env, action)

    env_class.step = counted
    try:
        yield played
    finally:
        if own is None:
            del env_class.step
        else:
            env_class.step = own


def _replay_on_meta(build) -> list[str]:
    trainer = build("meta")
    graph = StepGraph(trainer.train_step, trainer, backend="trace")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # (a refusal is reported below)
            for _ in range(graph.warmup + 2):  # (the warm-up, the capture, one replay)
                graph()
    except Exception as err:  # noqa: BLE001
        return [_failure(err, "replaying the step as a CUDA graph would")]
    if graph.failed is not None:
        return [f"the step cannot be replayed as a CUDA graph: {graph.failed}"]
    return []


def check_domain(domain, algo: str, steps: int = 70) -> DeviceReport:
    """``check_any_device`` of a registered ``domain`` (a ``DomainSpec``) as ``algo`` builds it.

    Two seeds, two env rows and two evaluation episodes each (what ``hrl-torch check`` runs).
    """
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    def build(device: str):
        opts = RunOptions(seeds=[0, 1], envs_per_learner=2, eval_episodes=2, device=device)
        opts.progress = opts.tensorboard = opts.check_env = False
        return build_trainer(domain, algo, opts)

    return check_any_device(build, steps)
