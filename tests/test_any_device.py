"""Any device, no host reads (docs/design.md, "Any device"; issue 27).

``meta`` has CUDA's device rules and no data: a run built for it fails on any tensor left on
the CPU and on any value read back to the host. Every registered domain x algorithm builds
there with every tensor there; the configurations driven to no host read in a training step
run a step there, and ``HostSyncCounter`` guards that they stay at 0.
"""

import dataclasses

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.common.sync_count import HostSyncCounter, count_train_step
from hrl_torch.execution.executor import BadStepError
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.cuda_graph import StepGraph
from hrl_torch.training.deferred import raise_pending
from tests.cases import pair_params

PAIRS = [(name, algo) for name in registry.names() for algo in registry.get(name).algos]
#: configurations whose training step makes no host read (the counting test guards them):
#: every registered one, the four the issue names first (taxi MAXQ-Q, small-AGV HAR, the ship
#: hybrid, four-AGV Cooperative HRL)
NAMED = [("taxi", "maxq-q"), ("small-agv", "har"), ("ship-steering-earlier", "hybrid")]
NAMED.append(("four-agv-earlier", "cooperative"))
NO_HOST_READ = list(dict.fromkeys([*NAMED, *PAIRS]))


def test_every_registered_configuration_is_guarded():
    assert set(NO_HOST_READ) == set(PAIRS) and NO_HOST_READ[:4] == NAMED


def _options(device: str = "cpu") -> RunOptions:
    return RunOptions(
        seeds=[0, 1],
        envs_per_learner=2,
        progress=False,
        tensorboard=False,
        device=device,
        eval_episodes=0,
        check_env=False,
    )


def _tensors(obj, path: str, out: list, seen: set, depth: int = 0) -> None:
    """Every tensor reachable from ``obj`` (modules, project objects, containers)."""
    if id(obj) in seen or depth > 8:
        return
    seen.add(id(obj))
    if isinstance(obj, torch.Tensor):
        out.append((path, obj.device))
        return
    if isinstance(obj, torch.nn.Module):
        named = list(obj.named_buffers()) + list(obj.named_parameters())
        out.extend((f"{path}.{n}", t.device) for n, t in named)
    if isinstance(obj, dict):
        items = obj.items()
    elif isinstance(obj, (list, tuple)):
        items = enumerate(obj)
    elif hasattr(obj, "__dict__") and type(obj).__module__.split(".")[0] in (
        "hrl_torch",
        "envs",
        "agents",
    ):
        items = [(k, v) for k, v in vars(obj).items() if k != "_host"]  # (host copies)
    else:
        return
    for key, value in items:
        _tensors(value, f"{path}.{key}", out, seen, depth + 1)


@pytest.mark.parametrize(("domain", "algo"), pair_params(PAIRS))
def test_every_configuration_builds_on_meta_with_every_tensor_there(domain, algo):
    trainer = build_trainer(registry.get(domain), algo, _options("meta"))
    found: list = []
    _tensors(trainer, "trainer", found, set())
    assert found, "no tensor found: the walk is broken"
    assert [p for p, dev in found if dev.type != "meta"] == []


@pytest.mark.parametrize(("domain", "algo"), pair_params(NO_HOST_READ))
def test_a_training_step_reads_nothing_back(domain, algo, monkeypatch):
    import hrl_torch.common.devices
    import hrl_torch.multiagent.broadcast

    monkeypatch.setattr(hrl_torch.multiagent.broadcast, "STATIC_ROUNDS", True)  # as off the CPU
    monkeypatch.setattr(hrl_torch.common.devices, "STATIC_SHAPES", True)  # (masks, as off the CPU)
    trainer = build_trainer(registry.get(domain), algo, _options())
    # from the first step on, past a block of random draws (BatchRNG.AHEAD = 64)
    counter = count_train_step(trainer, 70, stacks=True)
    assert counter.total == 0, dict(counter.where)


def test_the_counter_counts_each_kind_of_host_read():
    x = torch.arange(6.0)
    with HostSyncCounter() as counter:
        x.sum().item()
        bool(x.any())
        (x > 2).nonzero()
        x[x > 2]
        x.tolist()
        x.unique()
        torch.zeros(3).add_(1)  # (no read)
    assert dict(counter.counts) == {
        "item": 2,
        "nonzero": 1,
        "bool-index": 1,
        "tolist": 1,
        "unique": 1,
    }


def test_a_nan_reward_is_raised_at_the_next_read_with_the_immediate_message():
    trainer = build_trainer(registry.get("taxi"), "maxq-q", _options())
    step_all = trainer.env._step_all

    def nan_in_row_1(action):
        reward, duration, terminated = step_all(action)
        return reward.index_fill(0, torch.tensor([1]), float("nan")), duration, terminated

    trainer.train_step()
    trainer.env._step_all = nan_in_row_1
    trainer.train_step()  # (deferred: no raise inside the step)
    trainer.env._step_all = step_all
    trainer.train_step()
    with pytest.raises(BadStepError, match=r"env row 1 returned reward nan and duration"):
        raise_pending(trainer.deferred)


def test_an_action_outside_the_space_is_raised_by_train_with_the_immediate_message():
    trainer = build_trainer(registry.get("taxi"), "maxq-q", _options())
    step = trainer.env.step

    def bad_action_in_row_2(action):
        return step(action.index_fill(0, torch.tensor([2]), 9))

    trainer.env.step = bad_action_in_row_2
    with pytest.raises(
        ValueError, match=r"action 9 outside the action space \[0, 6\) \(env row 2\)"
    ):
        trainer.train(steps=4)


@pytest.mark.parametrize(("envs", "distinct"), [(1, True), (3, False)])
def test_the_executor_reads_whether_rows_share_a_learner_on_the_cpu(envs, distinct):
    opts = _options("meta")
    opts.envs_per_learner = envs
    trainer = build_trainer(registry.get("taxi"), "maxq-q", opts)
    assert trainer.executor.row_layout.distinct is distinct
    assert trainer.learner.rows_distinct(trainer.executor.learner) is distinct


def test_a_multi_agent_action_outside_the_space_is_deferred_with_the_immediate_message():
    from envs.two_taxi import TwoTaxiEnv

    env = TwoTaxiEnv([0], 2)
    env.reset()
    check = env.defer_checks()
    env.step(torch.tensor([[0, 0], [0, 7]]))  # (no raise inside the step)
    err = check.error()
    assert isinstance(err, ValueError)
    assert str(err) == "action 7 of agent 1 outside the action space [0, 7) (env row 1)"


@pytest.mark.parametrize(
    ("domain", "algo"),
    [
        ("ship-steering-earlier", "hybrid"),
        ("ship-steering-earlier", "flat-pg"),
        ("ship-steering", "flat-pg"),  # (online, beta = 1: the entry-wise CPU weights)
        ("taxi-fuel-earlier", "hpgrl"),
    ],
)
def test_masked_updates_learn_the_tables_of_compacted_ones(domain, algo, monkeypatch):
    import hrl_torch.common.devices

    tables = []
    for static in (False, True):  # (the CPU's row compaction; the masks used off the CPU)
        monkeypatch.setattr(hrl_torch.common.devices, "STATIC_SHAPES", static)
        opts = _options()
        opts.envs_per_learner = 3
        trainer = build_trainer(registry.get(domain), algo, opts)
        for _ in range(150):
            trainer.train_step()
        state = trainer.learner.state_dict()
        tables.append({k: v.clone() for k, v in state.items() if torch.is_tensor(v)})
    a, b = tables
    assert len(a) > 2 and [k for k in a if not torch.equal(a[k], b[k])] == []


def test_a_bad_turning_rate_is_raised_by_train_with_the_immediate_message():
    trainer = build_trainer(registry.get("ship-steering-earlier"), "flat-pg", _options())
    step = trainer.env.step

    def bad_rate_in_row_1(action):
        return step(action.index_fill(0, torch.tensor([1]), 99.0))

    trainer.env.step = bad_rate_in_row_1
    message = r"turning rate 99.0 outside \[-15.0, 15.0\] deg/s \(env row 1\)"
    with pytest.raises(ValueError, match=message):
        trainer.train(steps=4)


def test_a_full_pg_ring_is_raised_at_the_next_read_with_the_immediate_message():
    opts = _options()
    trainer = build_trainer(registry.get("taxi-fuel-earlier"), "hpgrl", opts)
    # (rings of 3 entries: the first longer invocation; a copy: the domain's config is shared)
    trainer.learner.config = dataclasses.replace(trainer.learner.config, trace_len=2)
    trainer.learner._rows.clear()
    for _ in range(12):
        trainer.train_step()  # (deferred: no raise inside the step)
    with pytest.raises(RuntimeError, match=r"selected more than trace_len=2 children"):
        raise_pending(trainer.deferred)


@pytest.mark.parametrize(("domain", "algo"), pair_params(NO_HOST_READ))
def test_every_configuration_is_replayed_on_meta_with_nothing_copied_from_the_host(domain, algo):
    """The CUDA-graph rules without a GPU: the step replays, reading and copying nothing.

    The graph's device clock and counters are on (as on a GPU); a copy of host data to the
    device (``TABLE.to(device)`` in a step: a synchronising copy a capture refuses) or a read
    back would refuse the replay here (``StepGraph.failed``) or raise on ``meta``.
    """
    trainer = build_trainer(registry.get(domain), algo, _options("meta"))
    graph = StepGraph(trainer.train_step, trainer, backend="trace")
    for _ in range(graph.warmup + 2):  # (the warm-up, the capture and one replay)
        graph()
    assert graph.failed is None and graph.graph is not None
    assert trainer.executor.stack.inst.device.type == "meta"
    assert all(b.device.type == "meta" for b in trainer.learner.buffers())


@pytest.mark.parametrize(("domain", "algo"), NAMED[:2])
def test_an_eager_step_off_the_cpu_copies_nothing_from_the_host(domain, algo):
    """Eager (no graph), past new blocks of random draws: no blocking copy of host data."""
    trainer = build_trainer(registry.get(domain), algo, _options("meta"))
    for _ in range(3):  # (constants copied to the device on first use)
        trainer.train_step()
    counter = count_train_step(trainer, 70, stacks=True)  # (BatchRNG.AHEAD = 64)
    assert dict(counter.where) == {}


@pytest.mark.parametrize(
    ("domain", "algo"), [("taxi", "maxq-q"), ("ship-steering-earlier", "hybrid")]
)
def test_the_collector_path_reads_nothing_back_per_step(domain, algo, monkeypatch):
    """TorchRL's ``Collector`` steps the domain: no read per step there either.

    (``EnvBase.maybe_reset`` would read ``done.any()`` twice a step, and a Task-Stack handed
    back by the rollout reset the executor's quiet subtask guard, which then read every step.)
    TorchRL's collector refuses ``meta``, so this counts on the CPU with the off-CPU rules.
    """
    import hrl_torch.common.devices

    monkeypatch.setattr(hrl_torch.common.devices, "STATIC_SHAPES", True)
    opts = _options()
    opts.collector = True
    trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(3):
        trainer.train_step()
    assert dict(count_train_step(trainer, 70, stacks=True).where) == {}


def test_the_documented_two_rooms_example_replays_on_meta():
    """The walkthrough's env (docs/your-own-hierarchy.md) keeps the any-device rules."""
    from hrl_torch.learners import MaxQLearner
    from hrl_torch.modules.exploration import EpsilonGreedy
    from hrl_torch.training.config import TrainConfig
    from hrl_torch.training.trainer import Trainer
    from scripts.example_two_rooms import TwoRoomsEnv, two_rooms_hierarchy

    graph = two_rooms_hierarchy()
    learner = MaxQLearner(graph, 2, alpha=0.5, gamma=1.0).to("meta")
    env = TwoRoomsEnv([0, 1], envs_per_learner=2).to("meta")
    config = TrainConfig(steps=10, eval_every=0, progress=False)
    trainer = Trainer(env, graph.to("meta"), learner, EpsilonGreedy(0.1), config)
    step = StepGraph(trainer.train_step, trainer, backend="trace")
    for _ in range(step.warmup + 2):
        step()
    assert step.failed is None and step.graph is not None
