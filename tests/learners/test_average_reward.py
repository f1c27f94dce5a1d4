"""Update rules of the Chapter 4 learners: gains, continuous time, populations, hand checks."""

import pytest
import torch
from tensordict import TensorDict

from agents.small_agv import flat_graph, small_agv_hierarchy
from envs.agv_small import SmallAGVEnv
from hrl_torch.env.batched import BatchedEnv
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import (
    GainEstimate,
    HARLearner,
    HDRLearner,
    HHLearner,
    RARLearner,
    RVIQLearner,
)
from hrl_torch.learners.three_part import three_part_targets
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.schedules import Constant
from hrl_torch.modules.tables import TableBank
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer

HIERARCHICAL = {
    "har": lambda g, p, ct: HARLearner(g, p, 0.3, all_states=True, continuous=ct),
    "rar": lambda g, p, ct: RARLearner(g, p, 0.3, all_states=True, continuous=ct),
    "hdr": lambda g, p, ct: HDRLearner(g, p, 0.3, 0.9, all_states=True, continuous=ct),
    "hh": lambda g, p, ct: HHLearner(g, p, continuous=ct),
}


def make_trainer(learner, env, graph, epsilon=0.3, record=8):
    config = TrainConfig(steps=10**9, eval_every=0, progress=False)
    executor = ExecutorConfig(record_visited=record)
    return Trainer(env, graph, learner, EpsilonGreedy(Constant(epsilon)), config, None, executor)


def learner_tensors(learner, p=None):
    """Every learned tensor (tables and gain sums), of all learners or of learner ``p``."""
    out = {}
    for name, module in learner.named_modules():
        if isinstance(module, TableBank):
            out[name] = module.data if p is None else module.data[p]
    for name, buf in learner.named_buffers():
        if not name.endswith("store") and buf.dim() > 0 and name in learner.state_dict():
            out[name] = buf if p is None else buf[p]
    return {k: v.clone() for k, v in out.items()}


class Recorder:
    """Wraps ``learner.update`` and keeps every batch it saw."""

    def __init__(self, learner):
        self.batches, self.update = [], learner.update
        learner.update = self

    def __call__(self, batch, step):
        self.batches.append(batch.clone())
        self.update(batch, step)


# ----------------------------------------------------------------------------- gains
@pytest.mark.parametrize("algo", ["har", "hh"])
def test_global_gain_is_reward_over_time_of_greedy_primitive_steps(algo):
    g = small_agv_hierarchy()
    learner = HIERARCHICAL[algo](g, 3, False)
    rec = Recorder(learner)
    make_trainer(learner, SmallAGVEnv([0, 1, 2], 4), g).train(steps=300 * 4)
    reward = torch.zeros(3, dtype=torch.float64)
    time = torch.zeros(3, dtype=torch.float64)
    for b in rec.batches:
        seen = (b["primitive", "valid"] & b["primitive", "greedy"]).double()
        reward.index_add_(0, b["learner"], b["primitive", "reward"].double() * seen)
        time.index_add_(0, b["learner"], seen)  # one step per primitive in discrete time
    assert torch.equal(learner.gains.reward[:, 0], reward)
    assert torch.equal(learner.gains.time[:, 0], time)
    assert torch.allclose(learner.gain.double(), reward / time)
    exploring = sum(
        int((b["primitive", "valid"] & ~b["primitive", "greedy"]).sum()) for b in rec.batches
    )
    assert exploring > 100  # random steps happened and were left out


def test_rar_gain_of_each_subtask_is_reward_over_time_of_its_greedy_children():
    g = small_agv_hierarchy()
    learner = HIERARCHICAL["rar"](g, 2, False)
    rec = Recorder(learner)
    make_trainer(learner, SmallAGVEnv([5, 6], 4), g).train(steps=300 * 4)
    reward = torch.zeros(2, g.n_nodes, dtype=torch.float64)
    steps = torch.zeros(2, g.n_nodes, dtype=torch.float64)
    for b in rec.batches:
        seen = (b["level", "valid"] & b["level", "greedy"]).double()
        idx = (b["learner"][:, None] * g.n_nodes + b["level", "node"]).reshape(-1)
        reward.view(-1).index_add_(0, idx, (b["level", "reward"].double() * seen).reshape(-1))
        steps.view(-1).index_add_(0, idx, (b["level", "steps"].double() * seen).reshape(-1))
    assert torch.equal(learner.gains.reward, reward)
    assert torch.equal(learner.gains.time, steps)
    navs = torch.tensor([g.index[n] for n in ("NavM1", "NavM2", "NavG1", "NavG2")])
    seen = steps[:, navs] > 0
    assert seen.sum() >= 4  # every step costs -1 inside navigation: gain exactly -1
    assert (learner.gain[:, navs][seen] == -1.0).all()
    assert (learner.gain[:, g.node_is_primitive] == 0).all()


def test_gain_prior_counts_as_initial_sums():
    gains = GainEstimate(2, 1, prior=(1.0, 10.0))
    assert torch.allclose(gains.gain, torch.ones(2, 1))
    gains.add(
        torch.tensor([0, 0]),
        0,
        torch.tensor([-1.0, -1.0]),
        torch.tensor([1.0, 1.0]),
        torch.tensor([True, False]),
    )
    assert gains.gain[0, 0] == pytest.approx(9 / 11) and gains.gain[1, 0] == 1.0
    assert (GainEstimate(1).gain == 0).all()  # no time yet


# ----------------------------------------------------------------------------- time
@pytest.mark.parametrize("algo", ["har", "rar", "hdr", "hh", "rvi-q"])
def test_continuous_time_with_unit_durations_equals_discrete_time(algo):
    tables = []
    for continuous in (False, True):
        if algo == "rvi-q":
            g = flat_graph()
            learner = RVIQLearner(g, 2, 0.3, continuous=continuous)
        else:
            g = small_agv_hierarchy()
            learner = HIERARCHICAL[algo](g, 2, continuous)
        make_trainer(learner, SmallAGVEnv([1, 2], 4), g).train(steps=250 * 4)
        tables.append(learner_tensors(learner))
    assert tables[0].keys() == tables[1].keys()
    for k, v in tables[0].items():
        assert torch.equal(v, tables[1][k]), k
    assert any(v.abs().sum() > 0 for k, v in tables[0].items() if v.dtype.is_floating_point)


class TwoStepEnv(BatchedEnv):
    """States 0 -> 1 -> 0 ...: action 0 moves on, reward 2 and duration 3 out of state 0,
    reward 1 and duration 0.5 out of state 1 (one env row)."""

    state_keys = ("state",)
    observation_sizes = {"observation": 2}

    def __init__(self):
        super().__init__([0], 1, 1)
        self.state = torch.zeros(1, dtype=torch.long)

    def _reset_rows(self, mask):
        self.state = torch.where(mask, 0, self.state)

    def _step_all(self, action):
        reward = torch.where(self.state == 0, 2.0, 1.0)
        tau = torch.where(self.state == 0, 3.0, 0.5)
        self.state = 1 - self.state
        return reward, tau, torch.zeros(1, dtype=torch.bool)

    def _observe(self):
        return {"observation": self.state}


def two_step_graph(with_subtask: bool):
    """Root -> Go -> a (Go ends after every step) or Root -> a (flat)."""
    by_state = dict(n_states=2, abstract=lambda o: o["observation"])
    prim = Primitive("a", 0, **by_state)
    if not with_subtask:
        return TaskGraph("Root", [Subtask("Root", ["a"], **by_state), prim], 1)
    go = Subtask(
        "Go",
        ["a"],
        **by_state,
        terminated=lambda o: torch.ones_like(o["observation"], dtype=torch.bool),
        event_termination=True,
    )
    return TaskGraph("Root", [Subtask("Root", ["Go"], **by_state), go, prim], 1)


def two_steps(learner, graph):
    trainer = make_trainer(learner, TwoStepEnv(), graph, epsilon=0.0, record=0)
    trainer.train(steps=2)
    return trainer


def test_continuous_time_har_by_hand():
    g = two_step_graph(True)
    learner = HARLearner(g, 1, alpha=1.0, continuous=True)
    two_steps(learner, g)
    # step 1: out of state 0, r = 2, tau = 3, gain 0 before (line 5), then g = 2 / 3
    # step 2: out of state 1, r = 1, tau = 0.5: H(a, 1) = 1 - (2/3) 0.5; g = 3 / 3.5
    prim = int(g.inst_children[1, 0])
    assert learner.V.view(prim)[:, 0].tolist() == pytest.approx([2.0, 1 - 1 / 3])
    assert float(learner.gain[0]) == pytest.approx(3 / 3.5)
    # Go ends after each step: C of Go is 0 (terminal); CE(Go, 0, a) <- W(Root, s' = 1)
    assert learner.C.view(1).abs().sum() == 0


def test_continuous_time_rar_by_hand():
    g = two_step_graph(True)
    learner = RARLearner(g, 1, alpha=1.0, continuous=True)
    two_steps(learner, g)
    go, root = g.index["Go"], g.root
    # Go: C(Go, s, a) <- 0 (terminal) - (g_Go - 0) tau with g_Go before the step (0, then 2/3)
    assert learner.C.view(go)[:, 0].tolist() == pytest.approx([0.0, -(2 / 3) * 0.5])
    # Root, step 1: L(root, 1) = H(Go, 1) + C(root, 1, Go) = 1 (V(a, 1) unseen: 0 + C...)
    assert float(learner.gain[0, go]) == pytest.approx(3 / 3.5)
    assert float(learner.gain[0, root]) == pytest.approx(3 / 3.5)


def test_continuous_time_rvi_q_by_hand():
    g = two_step_graph(False)
    learner = RVIQLearner(g, 1, alpha=0.5, continuous=True)
    two_steps(learner, g)
    # step 1: f(Q) = 0: Q(0) <- 0.5 * (2 - 0 * 3 + max Q(1) = 0) = 1; f = 1 / 2
    # step 2: Q(1) <- 0.5 * (1 - 0.5 * 0.5 + Q(0) = 1) = 0.875
    assert learner.Q.view(g.root)[:, 0].tolist() == pytest.approx([1.0, 0.875])
    assert float(learner.gain[0]) == pytest.approx((1.0 + 0.875) / 2)


def test_continuous_time_rvi_q_time_unit():
    g = two_step_graph(False)
    learner = RVIQLearner(g, 1, alpha=0.5, continuous=True, time_unit=0.5)
    two_steps(learner, g)
    # durations count double: step 1 as above (f = 0); f = 1 / 2 per half unit, then
    # Q(1) <- 0.5 * (1 - 0.5 * 1 + Q(0) = 1) = 0.75; the gain is per original unit
    assert learner.Q.view(g.root)[:, 0].tolist() == pytest.approx([1.0, 0.75])
    assert float(learner.gain[0]) == pytest.approx((1.0 + 0.75) / 2 / 0.5)


def test_hdr_discounts_by_duration():
    discount = HDRLearner(two_step_graph(True), 1, gamma=0.9, continuous=True).discount
    assert float(discount(torch.tensor(2.5))) == pytest.approx(0.9**2.5)
    c, ce = three_part_targets(
        torch.tensor([0.5, 0.5]),
        torch.tensor([False, True]),
        torch.tensor([4.0, 4.0]),
        torch.tensor([-2.0, -2.0]),
        torch.tensor([10.0, 10.0]),
    )
    assert c.tolist() == [2.0, 0.0] and ce.tolist() == [-1.0, 5.0]


# ----------------------------------------------------------------------------- populations
@pytest.mark.parametrize("algo", ["har", "rar", "hdr", "hh", "rvi-q"])
def test_population_equals_separate_runs(algo):
    seeds = [3, 8]

    def run(which):
        g = flat_graph() if algo == "rvi-q" else small_agv_hierarchy()
        if algo == "rvi-q":
            learner = RVIQLearner(g, len(which), 0.3)
        else:
            learner = HIERARCHICAL[algo](g, len(which), False)
        make_trainer(learner, SmallAGVEnv(which, 4), g).train(steps=200 * 4)
        return learner

    together = run(seeds)
    for p, seed in enumerate(seeds):
        alone = learner_tensors(run([seed]), 0)
        for k, v in learner_tensors(together, p).items():
            assert torch.equal(v, alone[k]), (seed, k)


def test_rvi_q_keeps_the_exact_sum_of_its_table():
    g = flat_graph()
    learner = RVIQLearner(g, 2, 0.5, init=0.25)
    make_trainer(learner, SmallAGVEnv([0, 1], 8), g).train(steps=300 * 8)
    exact = learner.Q.data.double().sum(1)
    assert torch.allclose(learner.q_sum, exact, rtol=0, atol=1e-3)
    assert torch.allclose(learner.gain.double(), exact / (78 * 6), atol=1e-6)


def test_flat_graph_is_required_by_rvi_q():
    with pytest.raises(ValueError, match="flat graph"):
        RVIQLearner(small_agv_hierarchy(), 1)


def test_hh_refuses_a_model_that_does_not_fit():
    from agents.agv import agv_hierarchy

    with pytest.raises(ValueError, match="dense model"):
        HHLearner(agv_hierarchy(), 1)


def test_greedy_table_reads_the_learner():
    from hrl_torch.training.continuing import greedy_table

    g = two_step_graph(True)
    learner = HARLearner(g, 1)
    obs = TensorDict({"observation": torch.arange(2)}, [2])
    assert greedy_table(learner, obs).shape == (g.n_instances, 2)


def test_rvi_q_reference_state_reads_its_best_action():
    g = flat_graph()
    learner = RVIQLearner(g, 2, 0.5, reference_state=7)
    make_trainer(learner, SmallAGVEnv([0, 1], 8), g).train(steps=100 * 8)
    assert torch.equal(learner.gain, learner.Q.data.view(2, 78, 6)[:, 7].amax(-1))
