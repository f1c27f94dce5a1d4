"""Replaying the training step as one captured graph (docs/design.md, "Any device").

A CUDA graph replays the kernels of one captured step with the scalars and addresses of that
step: it is the eager step only if the step reads nothing back to the host, keeps its state
where the next step reads it, and does the same ops every step. ``StepGraph`` makes a step so:

* the random streams draw from a counter on the device (``BatchRNG.count_on_device``), the
  schedules read a device clock (``HierarchicalAgent.count_on_device``), the executor checks
  its subtask guard every step (``static_guard``) and the learners mask rows instead of
  compacting them (``static_rows``), so no step differs;
* state the step replaces (``self.x = torch.where(...)``: the project's functional style) is
  copied back into the tensors the step read, inside the graph, and the attributes are pointed
  at those again (``_copy_back``);
* Python integers the step moves (the clock, the streams' counters) move by the same amount
  every step (checked over the warm-up); after each replay they are moved on by it.

The capture runs after ``warmup`` eager steps. ``backend="cuda"`` captures with
``torch.cuda.CUDAGraph``; ``backend="trace"`` (any device: the CPU tests) records the step's
aten ops with a ``TorchDispatchMode`` and replays them, each op re-run on the tensors the
recorded one read (state) or on the replayed outputs of earlier ops, the same semantics as a
graph's replay. ``backend="inductor"`` (the CPU, ``TrainConfig.compile_step``) compiles that
recorded step into one call (``hrl_torch.training.trace_compile``). A step that cannot be captured,
or compiled, falls back to eager steps with a warning.
"""

from __future__ import annotations

import contextlib
import gc
import warnings
from collections.abc import Callable

import torch
from torch.utils._python_dispatch import TorchDispatchMode

from hrl_torch.common.devices import attributes_of
from hrl_torch.common.rng import BatchRNG
from hrl_torch.common.sync_count import DATA_DEPENDENT, HostSyncCounter
from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.learners.base import Learner
from hrl_torch.training.agent import HierarchicalAgent
from hrl_torch.training.trace_compile import compile_trace

_PACKAGES = ("hrl_torch", "envs", "agents", "tensordict")


class NotReplayable(RuntimeError):
    """The step cannot be replayed as a graph (the message says why)."""


def _children(obj):
    """``(container, key, value)`` of what ``obj`` holds, for the walks below."""
    if isinstance(obj, dict):
        return [(obj, k, v) for k, v in list(obj.items())]
    if isinstance(obj, list):
        return [(obj, i, v) for i, v in enumerate(obj)]
    if isinstance(obj, tuple):
        return [(None, i, v) for i, v in enumerate(obj)]
    if isinstance(obj, StepGraph):  # (the graph itself is no state of the step)
        return []
    package = type(obj).__module__.split(".")[0]
    attributes = attributes_of(obj)
    if attributes is not None and (package in _PACKAGES or isinstance(obj, torch.nn.Module)):
        return [(attributes, k, v) for k, v in list(attributes.items())]
    return []


def walk(root) -> tuple[dict, dict, list]:
    """Tensor slots, integer slots and random streams reachable from ``root``.

    Slots are ``{path: (container, key, value)}``, ``path`` the keys from ``root`` (stable
    when a step rebuilds a dict), ``container`` a dict or list (``None`` inside a tuple:
    readable, not replaceable).
    """
    tensors: dict = {}
    ints: dict = {}
    rngs: list = []
    seen: set = set()
    stack = [((), root)]
    while stack:
        path, obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, BatchRNG):
            rngs.append(obj)
        for container, key, value in reversed(_children(obj)):
            slot = (*path, key)
            if isinstance(value, torch.Tensor):
                if container is not None:
                    tensors[slot] = (container, key, value)
            elif isinstance(value, int) and not isinstance(value, bool):
                if container is not None:
                    ints[slot] = (container, key, value)
            elif not isinstance(value, (str, float, bytes, type(None), bool)):
                stack.append((slot, value))
    return tensors, ints, rngs


def _int_delta(before: dict, after: dict) -> dict:
    """``{path: after - before}`` of the integer slots that moved."""
    return {
        s: after[s][2] - before[s][2] for s in after if s in before and after[s][2] != before[s][2]
    }


def _copy_back(before: dict, after: dict) -> None:
    """Copy each replaced tensor's new value into the one the step read; point the slot back.

    Runs inside the capture, so the graph ends with the copies: every replay reads and writes
    the same tensors. A slot that appeared, changed shape, or shared its tensor with a slot
    that kept it (or took another) cannot be replayed.
    """
    olds = {id(v[2]) for v in before.values()}
    moves, by_old = [], {}
    for slot, (container, key, new) in after.items():
        if slot not in before:
            raise NotReplayable(f"the step made a new tensor slot {slot} after the warm-up")
        old = before[slot][2]
        if by_old.setdefault(id(old), new) is not new:
            raise NotReplayable(f"the step gave slots sharing one tensor different ones ({slot})")
        if new is old:
            continue
        if new.shape != old.shape or new.dtype != old.dtype or new.device != old.device:
            raise NotReplayable(f"the step replaced {slot} by a tensor of another shape/dtype")
        moves.append((container, key, old, new.clone() if id(new) in olds else new))
    for container, key, old, new in moves:
        if old.data_ptr() != new.data_ptr():
            old.copy_(new)
        container[key] = old


#: ops that make a tensor from host data (``torch.tensor(list)``, ``as_tensor(int)``): on a GPU
#: a copy from pageable host memory, which a capture refuses (and a replay would repeat stale)
_FROM_HOST = (torch.ops.aten.lift_fresh.default, torch.ops.aten.lift_fresh_copy.default)


class _ReplayCheck(HostSyncCounter):
    """``HostSyncCounter`` that also counts tensors made from host data (``"from_host"``)."""

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func in _FROM_HOST:
            self._count("from_host")
        return super().__torch_dispatch__(func, types, args, kwargs)


class _Trace(TorchDispatchMode):
    """Records the aten ops of a step (``backend="trace"``); a host read is refused."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: list = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if DATA_DEPENDENT.get(func) is not None or func in _FROM_HOST:
            raise NotReplayable(f"the step reads the device back or copies host data ({func})")
        out = func(*args, **kwargs)
        self.ops.append((func, args, kwargs, out))
        return out


def _flat(x) -> list:
    return list(x) if isinstance(x, (list, tuple)) else [x]


def replay_trace(ops: list) -> None:
    """Re-run recorded ops: earlier outputs replaced by their replayed ones, others as read."""
    made: dict = {}

    def sub(x):
        if isinstance(x, torch.Tensor):
            return made.get(id(x), x)
        if isinstance(x, (list, tuple)):
            return type(x)(sub(v) for v in x)
        return x

    # (the recorded ops sit below autograd, a neural learner's backward ops among them: a
    # replay, like a CUDA graph's, re-runs them without building another autograd graph)
    with torch.no_grad():
        for func, args, kwargs, out in ops:
            new = func(*sub(args), **{k: sub(v) for k, v in kwargs.items()})
            for o, n in zip(_flat(out), _flat(new), strict=True):
                if isinstance(o, torch.Tensor):
                    made[id(o)] = n


class StepGraph:
    """``step()`` replayed as one graph after ``warmup`` eager steps (module docstring).

    Args:
        step: the training step (no arguments).
        root: the object holding every piece of the step's state (the trainer).
        warmup: eager steps before the capture (the last two check the integer moves and
            host reads; at least 2).
        backend: ``"cuda"`` (``torch.cuda.CUDAGraph``), ``"trace"`` (recorded aten ops) or
            ``"inductor"`` (those ops compiled, ``hrl_torch.training.trace_compile``).

    ``failed`` says why a step could not be captured (then every step runs eagerly).
    """

    def __init__(self, step: Callable[[], None], root, warmup: int = 3, backend="cuda") -> None:
        if backend not in ("cuda", "trace", "inductor"):
            raise ValueError(f"backend must be 'cuda', 'trace' or 'inductor', got {backend!r}")
        self.step_fn, self.root, self.backend = step, root, backend
        self.warmup = max(int(warmup), 2)
        self.steps = 0  # steps taken (eager and replayed)
        self.graph = None  # the captured graph (cuda) or op list (trace)
        self.failed: str | None = None
        self._inside = False
        self.delta: dict = {}  # path -> how much the step moves that Python integer
        self._deltas: list[dict] = []
        self._int_slots: list = []
        _, _, self._rngs = walk(root)
        for rng in self._rngs:  # (same numbers, drawn from a device counter)
            rng.count_on_device()
        for agent in _reachable(root, HierarchicalAgent):  # (the schedules read a device clock)
            agent.count_on_device()
        for executor in _reachable(root, HierarchicalExecutor):
            executor.static_guard = True
        for learner in _reachable(root, Learner):  # (masks, not row compaction, on the CPU too)
            for module in learner.modules():
                if isinstance(module, Learner):
                    module.static_rows = True

    def _eager(self) -> None:
        self.step_fn()
        for rng in self._rngs:
            rng.sync_counter()

    def __call__(self) -> bool:
        """One training step: eager in the warm-up (or after a refused capture), else replayed.

        True; False when called from inside its own step (the caller then steps eagerly).
        """
        if self._inside:
            return False
        self._inside = True
        try:
            self._one_step()
        finally:
            self._inside = False
        return True

    def _one_step(self) -> None:
        if self.graph is not None:
            self._replay()
        elif self.failed is not None:
            self._eager()
        elif self.steps < self.warmup:
            self._warm_step()
        else:
            self._capture()
        self.steps += 1

    def _warm_step(self) -> None:
        before = walk(self.root)[1]
        counter = _ReplayCheck()
        side = self.backend == "cuda"
        if side:  # (CUDA: warm up on a side stream, as a capture needs)
            stream = torch.cuda.Stream()
            stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream) if side else contextlib.nullcontext(), counter:
            self._eager()
        if side:
            torch.cuda.current_stream().wait_stream(stream)
        self._deltas.append(_int_delta(before, walk(self.root)[1]))
        if counter.total and self.steps == self.warmup - 1:  # (the first may fill caches)
            self._refuse(f"the step reads the device back: {dict(counter.counts)}")

    def _refuse(self, why: str) -> None:
        self.failed = why
        warnings.warn(f"training step not captured, eager steps instead: {why}", stacklevel=3)

    def _capture(self) -> None:
        if len(self._deltas) < 2 or self._deltas[-1] != self._deltas[-2]:
            self._refuse(f"Python integers move unevenly per step: {self._deltas[-2:]}")
            self._eager()
            return
        self.delta = self._deltas[-1]
        tensors, ints, _ = walk(self.root)
        try:
            self.graph = self._record(tensors)
        except (NotReplayable, RuntimeError) as err:  # (the state is half stepped: stop)
            raise RuntimeError(
                f"capturing the training step failed ({err}); train with --no-cuda-graph"
            ) from err
        after = walk(self.root)[1]
        if _int_delta(ints, after) != self.delta:
            raise RuntimeError("the captured step moved Python integers unlike the warm-up")
        self._int_slots = [(after[p][0], after[p][1], d) for p, d in self.delta.items()]
        if self.backend == "inductor":
            self._compile()

    def _compile(self) -> None:
        """The recorded ops as one compiled call; if compiling fails, eager steps from now."""
        try:
            self.graph = compile_trace(self.graph)
        except Exception as err:  # noqa: BLE001  (any compiler failure: eager, said once)
            self.graph = None
            self._refuse(f"compiling the recorded step failed ({type(err).__name__}: {err})")

    def _record(self, tensors: dict):
        """Capture one step (it runs: the trace records while running; CUDA replays once)."""
        if self.backend != "cuda":
            with _Trace() as trace:
                self._eager()
                _copy_back(tensors, walk(self.root)[0])
            return trace.ops
        graph = torch.cuda.CUDAGraph()
        torch.cuda.synchronize()
        # no garbage collection inside the capture: a dead trainer's graph freed there resets
        # itself, which a capture refuses (on an H200: "operation not permitted when stream
        # is capturing (function reset)", then the capture failed)
        gc.collect()
        was_enabled = gc.isenabled()
        gc.disable()
        try:
            with torch.cuda.graph(graph):
                self._eager()
                _copy_back(tensors, walk(self.root)[0])
        finally:
            if was_enabled:
                gc.enable()
        graph.replay()  # (capturing ran no kernel: this is the captured step's work)
        return graph

    def _replay(self) -> None:
        if self.backend == "inductor":
            self.graph()
        elif self.backend == "trace":
            replay_trace(self.graph)
        else:
            self.graph.replay()
        for container, key, step in self._int_slots:  # (the graph runs no Python)
            container[key] += step


def _reachable(root, kind: type):
    """The objects of type ``kind`` reachable from ``root``."""
    seen: set = set()
    stack = [root]
    while stack:
        obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, kind):
            yield obj
        stack.extend(v for _, _, v in _children(obj) if not isinstance(v, torch.Tensor))


#: batch rows from which a CUDA step is not captured (eager instead): there the launches a
#: replay saves are under 2% of the step (taxi MAXQ-Q on an H200: 9.36 against 9.51 ms at
#: 100 x 2048, 39.0 against 36.3 at 1000 x 1024), and a replayed PG step must take the static
#: pass over every ring (``pg_traces.STATIC_RING_ENTRIES``). ``Trainer.graph_backend`` and
#: ``compile_step`` are not limited.
CUDA_GRAPH_MAX_ROWS = 1 << 16
#: PG ring entries (``pg_traces.ring_entries``) from which a CUDA step is not captured: a
#: replay reads every entry at every step, about 16 ns each on an H200 (the ship hybrid:
#: 1.3M entries at 10 x 512 replayed in 21.7 ms against 24.1 eager and compacted; 51M at
#: 100 x 2048, 817 ms static against 45.8 compacted)
CUDA_GRAPH_MAX_RING_ENTRIES = 1 << 21


def _replay_pays(trainer) -> bool:
    """Whether a CUDA graph of ``trainer``'s step is worth capturing (the limits above)."""
    rows, modules = trainer.rows.numel(), trainer.learner.modules()
    rings = max((m.ring_entries(rows) for m in modules if isinstance(m, Learner)), default=0)
    return rows < CUDA_GRAPH_MAX_ROWS and rings < CUDA_GRAPH_MAX_RING_ENTRIES


def step_for(trainer) -> Callable[[], bool]:
    """What ``Trainer.train_step`` asks first: a ``StepGraph`` of it where it replays.

    Replayed on a CUDA device with ``TrainConfig.cuda_graph`` (``backend="cuda"``) below
    ``CUDA_GRAPH_MAX_ROWS`` batch rows and ``CUDA_GRAPH_MAX_RING_ENTRIES``, compiled
    on the CPU with ``TrainConfig.compile_step`` (``"inductor"``), or with
    ``Trainer.graph_backend`` (``"trace"``: any device, the CPU tests); never with the
    collector or for an agent that does not learn. Else a function that returns False (the
    trainer steps eagerly).
    """
    backend = trainer.graph_backend
    on_cuda = trainer.env.device.type == "cuda"
    if backend is None and trainer.config.cuda_graph and on_cuda:
        backend = "cuda" if _replay_pays(trainer) else None
    if backend is None and trainer.config.compile_step and trainer.env.device.type == "cpu":
        backend = "inductor"
    if backend is None or trainer.collector or not trainer.agent.learn:
        return lambda: False
    return StepGraph(trainer.train_step, trainer, backend=backend)
