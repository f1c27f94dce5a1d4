"""The training step replayed as one graph (hrl_torch.training.cuda_graph; issue 27 point 4).

A CUDA graph replays the captured step's kernels on the captured addresses. ``backend="trace"``
has the same semantics on any device (each recorded aten op re-run on the tensors the capture
read, or on the replayed outputs of earlier ops), so the CPU checks here are what a replay
would compute: same tables as the eager step, state in fixed buffers, no host read. The
CUDA-only tests compare the real graph with the eager step where a GPU is present.
"""

import warnings

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.common.rng import BatchRNG
from hrl_torch.common.sync_count import HostSyncCounter
from hrl_torch.modules.schedules import Exponential, Linear
from hrl_torch.runs import registry
from hrl_torch.runs.cli_parser import parser as cli_parser
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.cuda_graph import StepGraph, walk
from hrl_torch.training.trace_compile import trace_module
from hrl_torch.training.trainer import Trainer

NAMED = [("taxi", "maxq-q"), ("small-agv", "har"), ("ship-steering-earlier", "hybrid")]
NAMED.append(("four-agv-earlier", "cooperative"))
OTHERS = [
    ("taxi-fuel-earlier", "hpgrl"),
    ("ship-steering-earlier", "flat-pg"),
    ("two-taxi-earlier", "com-1"),
]
#: the text's two-taxi task: its masks index constant buffers, no tensor made from host data
OTHERS += [("two-taxi", "com-1"), ("two-taxi-station", "cooperative")]


def _trainer(domain, algo, device="cpu", **kw):
    kw = {"eval_episodes": 0, "check_env": False, "envs_per_learner": 2, **kw}
    opts = RunOptions(seeds=[0, 1], progress=False, tensorboard=False, device=device, **kw)
    return build_trainer(registry.get(domain), algo, opts)


def _tables(trainer) -> dict:
    state = trainer.learner.state_dict()
    return {k: v.detach().cpu().clone() for k, v in state.items() if torch.is_tensor(v)}


@pytest.mark.parametrize(("domain", "algo"), NAMED + OTHERS)
def test_a_replayed_step_learns_the_eager_tables(domain, algo):
    eager, replayed = _trainer(domain, algo), _trainer(domain, algo)
    graph = StepGraph(replayed.train_step, replayed, backend="trace")
    for _ in range(80):
        eager.train_step()
        graph()
    assert graph.failed is None and graph.graph is not None
    assert replayed.step == eager.step == 160
    a, b = _tables(eager), _tables(replayed)
    assert [k for k in a if not torch.equal(a[k], b[k])] == []
    assert torch.equal(eager.executor.stack.inst, replayed.executor.stack.inst)


@pytest.mark.parametrize(
    ("domain", "algo"), [("taxi", "maxq-q"), ("ship-steering-earlier", "hybrid")]
)
def test_the_replayed_step_keeps_its_state_in_fixed_buffers_and_reads_nothing(domain, algo):
    trainer = _trainer(domain, algo)
    graph = StepGraph(trainer.train_step, trainer, backend="trace")
    for _ in range(graph.warmup + 1):  # (the last: the capture)
        graph()
    before = {p: v[2].data_ptr() for p, v in walk(trainer)[0].items()}
    with HostSyncCounter() as counter:
        for _ in range(5):
            graph()
    after = {p: v[2].data_ptr() for p, v in walk(trainer)[0].items()}
    assert counter.total == 0
    assert before == after  # every slot the same storage: what a CUDA graph replays on


def test_train_with_the_trace_backend_evaluates_as_the_eager_run(monkeypatch):
    results = []
    for backend in (None, "trace"):
        monkeypatch.setattr(Trainer, "graph_backend", backend, raising=False)
        trainer = _trainer("taxi", "maxq-q", steps=160, eval_every=40, eval_episodes=3)
        results.append((trainer.train(), _tables(trainer), trainer))
    (eager, a, _), (replayed, b, trainer) = results
    assert trainer._graph.graph is not None
    assert len(eager.curve) == 4 and eager.curve == replayed.curve
    assert [k for k in a if not torch.equal(a[k], b[k])] == []


def test_a_step_that_reads_the_device_runs_eagerly_with_a_warning():
    x = torch.zeros(3)

    class Root:
        pass

    def step():
        x.add_(1.0)
        if float(x.sum()) > 100:  # a host read
            x.zero_()

    graph = StepGraph(step, Root(), backend="trace")
    with pytest.warns(UserWarning, match="reads the device back"):
        for _ in range(6):
            graph()
    assert graph.graph is None and torch.equal(x, torch.full((3,), 6.0))


def test_device_counted_draws_are_the_block_draws():
    cols = torch.tensor([[1, 4], [0, 2]])
    a, b = BatchRNG([3, 5], 2, "x"), BatchRNG([3, 5], 2, "x")
    b.count_on_device()
    for rng in (a, b):
        rng.know_columns(cols, [1, 4, 0, 2])
    rows = torch.tensor([1, 3])
    for _ in range(70):  # (past a block of AHEAD = 64)
        for draw in (lambda r: r.uniform(), lambda r: r.uniform(6), lambda r: r.integers(7, 3)):
            assert torch.equal(draw(a), draw(b))
        assert torch.equal(a.uniform(6, columns=cols), b.uniform(6, columns=cols))
        assert torch.equal(a.uniform_rows(6, 5, rows, cols[0]), b.uniform_rows(6, 5, rows, cols[0]))
        b.sync_counter()
    assert int(b.device_counter) == b.counter


@pytest.mark.parametrize("schedule", [Linear(0.5, 0.1, 1000), Exponential(0.3, 0.9, 50, 0.01)])
def test_a_schedule_on_a_device_clock_gives_the_float_values(schedule):
    for step in (0, 1, 7, 999, 1000, 5000):
        value = schedule(torch.tensor(step))
        assert value.dtype == torch.float64 and float(value) == schedule(step)


def test_no_cuda_graph_turns_the_replay_off():
    parser = cli_parser("0")
    args = parser.parse_args(["train", "taxi", "--algo", "maxq-q", "--no-cuda-graph"])
    assert args.no_cuda_graph
    assert not parser.parse_args(["train", "taxi", "--algo", "maxq-q"]).no_cuda_graph
    assert not _trainer("taxi", "maxq-q", cuda_graph=False).config.cuda_graph


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize(("domain", "algo"), NAMED)
def test_the_cuda_graph_learns_the_eager_tables(domain, algo):
    runs = {}
    for graph in (True, False):
        trainer = _trainer(domain, algo, device="cuda", cuda_graph=graph)
        with warnings.catch_warnings():
            warnings.filterwarnings("error", message="training step not captured")
            for _ in range(80):
                trainer.train_step()
        if graph:
            assert trainer._graph.graph is not None
        runs[graph] = _tables(trainer)
    a, b = runs[True], runs[False]
    assert [k for k in a if not torch.equal(a[k], b[k])] == []


def _compiled_and_eager_runs(eval_episodes: int = 3, eval_max_steps: int | None = None) -> list:
    runs = []
    for compile_step in (False, True):
        trainer = _trainer(
            "taxi", "maxq-q", steps=160, eval_every=40, eval_episodes=eval_episodes,
            compile_step=compile_step,
        )  # fmt: skip
        if eval_max_steps:
            trainer.config.eval_max_steps = eval_max_steps
        runs.append((trainer.train(), _tables(trainer), trainer))
    return runs


@pytest.mark.slow  # (inductor compiles C++: a minute or more on an empty cache)
def test_the_compiled_step_learns_the_eager_tables():
    (eager, a, first), (compiled, b, trainer) = _compiled_and_eager_runs()
    assert trainer.config.compile_step and trainer._graph.backend == "inductor"
    assert trainer._graph.failed is None and callable(trainer._graph.graph)
    assert len(eager.curve) == 4 and eager.curve == compiled.curve
    assert [k for k in a if not torch.equal(a[k], b[k])] == []
    assert torch.equal(first.executor.stack.inst, trainer.executor.stack.inst)
    assert trainer.step == first.step


def test_the_recorded_step_as_one_fx_graph_learns_the_eager_tables(monkeypatch):
    """The graph ``compile_trace`` hands to inductor, run uncompiled: the fast suite's check of
    ``trace_module`` (inputs, in-place writes, tuple outputs) on the real step; the slow test
    above compiles it."""

    def uncompiled(ops):
        module, inputs = trace_module(ops)

        def replay() -> None:
            with torch.no_grad():
                module(*inputs)

        return replay

    monkeypatch.setattr("hrl_torch.training.cuda_graph.compile_trace", uncompiled)
    # (short evaluations: the curve only has to be the same, not long)
    runs = _compiled_and_eager_runs(eval_episodes=1, eval_max_steps=40)
    (eager, a, first), (compiled, b, trainer) = runs
    assert trainer.config.compile_step and trainer._graph.backend == "inductor"
    assert trainer._graph.failed is None and callable(trainer._graph.graph)
    assert len(eager.curve) == 4 and eager.curve == compiled.curve
    assert [k for k in a if not torch.equal(a[k], b[k])] == []
    assert torch.equal(first.executor.stack.inst, trainer.executor.stack.inst)
    assert trainer.step == first.step


def test_a_step_that_fails_to_compile_runs_eagerly_with_one_warning(monkeypatch):
    def fails(ops):
        raise RuntimeError("no compiler here")

    monkeypatch.setattr("hrl_torch.training.cuda_graph.compile_trace", fails)
    eager, compiled = _trainer("taxi", "maxq-q"), _trainer("taxi", "maxq-q", compile_step=True)
    with pytest.warns(UserWarning, match="compiling the recorded step failed") as caught:
        for _ in range(30):
            eager.train_step()
            compiled.train_step()
    assert len([w for w in caught if "compiling" in str(w.message)]) == 1
    assert compiled._graph.graph is None
    a, b = _tables(eager), _tables(compiled)
    assert [k for k in a if not torch.equal(a[k], b[k])] == []


def test_compile_step_is_off_unless_asked():
    parser = cli_parser("0")
    assert parser.parse_args(["train", "taxi", "--algo", "maxq-q", "--compile-step"]).compile_step
    assert not parser.parse_args(["train", "taxi", "--algo", "maxq-q"]).compile_step
    trainer = _trainer("taxi", "maxq-q")
    assert not trainer.config.compile_step
    trainer.train_step()
    assert trainer._graph() is False  # (the eager step: no StepGraph on the CPU by default)


def test_a_replayed_step_of_5120_rows_learns_the_eager_tables():
    # (at this size the eager CPU step chooses level by level for the choosing rows only,
    # compacted with a host read: a replayed step must not compact)
    eager = _trainer("taxi", "maxq-q", envs_per_learner=2560)
    replayed = _trainer("taxi", "maxq-q", envs_per_learner=2560)
    graph = StepGraph(replayed.train_step, replayed, backend="trace")
    for _ in range(12):
        eager.train_step()
        graph()
    assert graph.failed is None and graph.graph is not None
    a, b = _tables(eager), _tables(replayed)
    assert [k for k in a if not torch.equal(a[k], b[k])] == []
    assert torch.equal(eager.executor.stack.inst, replayed.executor.stack.inst)


def test_a_cuda_graph_is_captured_only_where_it_pays():
    from hrl_torch.training.cuda_graph import _replay_pays

    assert _replay_pays(_trainer("taxi", "maxq-q"))
    assert not _replay_pays(_trainer("taxi", "maxq-q", envs_per_learner=32768))  # 65,536 rows
    # the ship's rings: rows x 251 entries, under 2^21 with 8,192 rows, over with 8,356
    assert _replay_pays(_trainer("ship-steering-earlier", "hybrid", envs_per_learner=4096))
    assert not _replay_pays(_trainer("ship-steering-earlier", "hybrid", envs_per_learner=4178))
