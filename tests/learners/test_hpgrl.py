"""HPGRL (Algorithm 3): unbiased gradient estimates on a tiny hierarchy.

The estimates are compared with the exact gradient of the weighted reward-to-go ``chi_i``,
computed by dynamic programming over the hierarchy and differentiated with autograd.
"""

import functools

import pytest
import torch

from hrl_torch.common.rng import BatchRNG
from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners.pg import HPGRLLearner, PGConfig, PGPolicy
from hrl_torch.modules.exploration import Greedy
from hrl_torch.training.agent import with_values
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer
from tests.helpers import TableEnv

# a 5-state corridor: a0 moves right, a1 moves left (0 stays); reaching 4 ends the episode
N, TERMINAL = 5, 4
NEXT = torch.tensor([[1, 0], [2, 0], [3, 1], [4, 2], [4, 4]])
REWARD = torch.tensor([[-1.0, 0.5], [-0.5, -1.0], [0.3, -0.2], [1.0, -0.7], [0.0, 0.0]])
STARTS = torch.tensor([0, 1, 2, 3])
STOP = {"A": 3, "B": 0}  # A ends on reaching 3, B on reaching 0 (both: or the episode's end)
SHAPING_A = 2.0  # internal reward of A: 2 per right move
PSEUDO_B = 5.0  # internal reward of B: 5 on reaching 0


def hierarchy() -> TaskGraph:
    def state(o):
        return o["observation"]

    root = Subtask("Root", ["A", "B"], n_states=N, abstract=state)
    a = Subtask(
        "A",
        ["right", "left"],
        n_states=N,
        abstract=state,
        terminated=lambda o: o["observation"] == STOP["A"],
        shaping_reward=lambda o, act, o2: SHAPING_A * (act == 0).float(),
    )
    b = Subtask(
        "B",
        ["right", "left"],
        n_states=N,
        abstract=state,
        terminated=lambda o: o["observation"] == STOP["B"],
        pseudo_reward=lambda o: PSEUDO_B * (o["observation"] == STOP["B"]).float(),
    )
    return TaskGraph("Root", [root, a, b, Primitive("right", 0), Primitive("left", 1)], 2)


def initial_theta():
    """Random policies; the children lean right so that episodes stay short (low variance)."""
    g = torch.Generator().manual_seed(0)
    theta = {k: torch.randn(N, 2, generator=g) for k in ("Root", "A", "B")}
    for k in ("A", "B"):
        theta[k][:, 0] += 1.5
    return theta


def child_model(theta, name, internal):
    """Expected reward of child ``name`` from each state and its exit distribution ``[N, N]``."""
    mu = torch.softmax(theta, -1)
    exits = torch.zeros(N, dtype=torch.bool)
    exits[[STOP[name], TERMINAL]] = True
    move = torch.nn.functional.one_hot(NEXT, N).float()  # [N, 2, N]
    p = torch.einsum("sa,sat->st", mu, move)
    r = (mu * REWARD).sum(-1)
    if internal and name == "A":
        r = r + mu[:, 0] * SHAPING_A
    live = ~exits
    visits = torch.linalg.inv(torch.eye(int(live.sum())) - p[live][:, live])
    reward = torch.zeros(N).index_put((live.nonzero()[:, 0],), visits @ r[live])
    exit_p = torch.zeros(N, N).index_put((live.nonzero()[:, 0],), (visits @ p[live]) * exits)
    if internal and name == "B":
        reward = reward + PSEUDO_B * exit_p[:, STOP["B"]]
    return reward, exit_p


def root_objective(theta, propagate_internal=False):
    """chi_root: mean over the start states of the root's reward-to-go (external rewards)."""
    models = [child_model(theta[c], c, propagate_internal) for c in ("A", "B")]
    avail = torch.tensor([[s != STOP["A"], s != STOP["B"]] for s in range(N)])
    mu = torch.softmax(theta["Root"].masked_fill(~avail, -torch.inf), -1)
    b = sum(mu[:, k] * models[k][0] for k in range(2))
    m = sum(mu[:, k, None] * models[k][1] for k in range(2))
    live = torch.arange(N) != TERMINAL
    j = torch.linalg.solve(torch.eye(N - 1) - m[live][:, live], b[live])
    return j[STARTS].mean()


def exact_gradient(objective, theta, name):
    leaves = {k: v.clone().requires_grad_(True) for k, v in theta.items()}
    (grad,) = torch.autograd.grad(objective(leaves), leaves[name])
    return grad


@functools.cache  # (one run per setting, shared by the tests that only read it)
def run(online, n_learners=12, envs=128, episodes=24, baseline=0.0):
    """Frozen HPGRL: per learner, summed estimates and the invocations' start states.

    Each row counts its first ``episodes`` episodes and then nothing more: a horizon in steps
    would cut every row's last invocation, and dropping a cycle because it is still running
    keeps the short ones, a length bias of the order of (invocations per row)^-1 that this
    test's standard errors would see.
    """
    graph = hierarchy()
    seeds = list(range(n_learners))
    env = TableEnv(NEXT, REWARD, torch.arange(N) == TERMINAL, STARTS, seeds, envs)
    config = PGConfig(frozen=True, online=online, trace_len=400, baseline=baseline)
    learner = HPGRLLearner(graph, n_learners, config)
    theta = initial_theta()
    for p in range(n_learners):
        for k, value in theta.items():
            learner.group_view(k, p).copy_(value)
    executor = HierarchicalExecutor(graph, env.batch_size, envs, score_width=learner.score_width)
    policy = PGPolicy(learner, BatchRNG(seeds, envs, "explore"))
    rows = env.learner_of_row()
    starts = torch.zeros(n_learners, 2, N)  # start states of finished A and B invocations
    ctx = graph.context(env.reset(), rows)
    action = executor.act(ctx, policy, 0)
    finished = torch.zeros(env.batch_size)  # episodes each row has finished
    while bool((finished < episodes).any()):
        td = env.step(action)
        ctx = graph.context(td, rows)
        batch = executor.observe(td, ctx)
        counting = finished < episodes
        for part in ("level", "primitive"):
            valid = batch[part, "valid"]
            batch[part, "valid"] = valid & counting.view(-1, *[1] * (valid.dim() - 1))
        learner.update(with_values(batch, ctx), 0)
        done = batch["level", "valid"][:, 0]
        flat = (rows * 2 + batch["level", "child"][:, 0]) * N + batch["level", "state"][:, 0]
        starts.view(-1).index_add_(0, flat[done], torch.ones(int(done.sum())))
        finished += td["terminated"].float()
        action = executor.act(ctx, policy, 0)
    return learner, theta, starts


def per_learner_estimates(learner, group):
    k = learner.group_names.index(group)
    sums = torch.stack(
        [learner.group_view(group, p, "grad_sum") for p in range(learner.n_learners)]
    )
    return sums / learner.cycles[:, k, None, None]


def assert_unbiased(estimates, exact, z=4.0):
    """Mean over independent learners within ``z`` standard errors of ``exact`` (per entry)."""
    diff = estimates - exact
    se = diff.std(0) / len(diff) ** 0.5
    assert (diff.mean(0).abs() <= z * se + 1e-4).all(), (diff.mean(0), se)
    return diff.mean(0), se


@pytest.mark.parametrize("online", [False, True])
def test_root_gradient_estimate_is_unbiased_and_ignores_internal_rewards(online):
    learner, theta, _ = run(online=online)
    estimates = per_learner_estimates(learner, "Root")
    exact = exact_gradient(root_objective, theta, "Root")
    _, se = assert_unbiased(estimates, exact)
    assert (exact.abs() > 6 * se).any()  # a zero estimate would fail
    # the gradient of a root that saw its children's internal rewards is far from ours
    leaked = exact_gradient(lambda t: root_objective(t, True), theta, "Root")
    assert ((estimates.mean(0) - leaked).abs() > 6 * se).any()


def child_gradients(theta, name, weights, internal):
    """Exact gradient of ``sum_s I(s) J_i(s)`` for each learner's start weights ``[P, N]``."""

    def chi(t, w):
        return (w * child_model(t[name], name, internal)[0]).sum()

    return torch.stack([exact_gradient(lambda t, w=w: chi(t, w), theta, name) for w in weights])


def test_child_gradient_estimates_are_unbiased_with_internal_rewards():
    learner, theta, starts = run(online=False)
    for k, name in enumerate(("A", "B")):
        weights = starts[:, k] / starts[:, k].sum(-1, keepdim=True)  # empirical I_i per learner
        assert torch.equal(learner.cycles[:, k + 1], starts[:, k].sum(-1))
        estimates = per_learner_estimates(learner, name)
        _, se = assert_unbiased(estimates, child_gradients(theta, name, weights, True))
        # without its internal rewards the child's gradient would be another one
        external_only = child_gradients(theta, name, weights, False)
        assert ((estimates - external_only).mean(0).abs() > 6 * se).any()


def test_online_and_renewal_updates_sum_to_the_same_per_cycle():
    # one env: when an episode ends every invocation has ended, and both modes have applied
    # sum_k (R_k + r~_k) z_{k+1} of every cycle
    graph = hierarchy()
    results = []
    for online in (True, False):
        env = TableEnv(NEXT, REWARD, torch.arange(N) == TERMINAL, STARTS, [5], 1)
        learner = HPGRLLearner(graph, 1, PGConfig(frozen=True, online=online))
        for k, value in initial_theta().items():
            learner.group_view(k, 0).copy_(value)
        executor = HierarchicalExecutor(graph, 1, 1, score_width=learner.score_width)
        policy = PGPolicy(learner, BatchRNG([5], 1, "explore"))
        ctx = graph.context(env.reset())
        action = executor.act(ctx, policy, 0)
        episodes = 0
        while episodes < 3:
            td = env.step(action)
            ctx = graph.context(td)
            batch = executor.observe(td, ctx)
            learner.update(with_values(batch, ctx), 0)
            episodes += int(td["terminated"].sum())
            action = executor.act(ctx, policy, 0)
        results.append(learner.grad_sum.clone())
    assert results[0].abs().sum() > 0
    assert torch.allclose(results[0], results[1], atol=1e-5)


def test_training_samples_whatever_the_exploration_and_evaluation_records_nothing():
    # a PG learner trained with Greedy() exploration must still sample and learn; only the
    # trainer's evaluation acts on the modes
    graph = hierarchy()
    env = TableEnv(NEXT, REWARD, torch.arange(N) == TERMINAL, STARTS, [0, 1], 16)
    eval_env = TableEnv(NEXT, REWARD, torch.arange(N) == TERMINAL, STARTS, [7, 7], 4, 50)
    learner = HPGRLLearner(graph, 2, PGConfig(alpha=0.05, trace_len=400))
    trainer = Trainer(
        env, graph, learner, Greedy(), TrainConfig(steps=200, progress=False), eval_env=eval_env
    )
    assert not trainer.policy.greedy
    trainer.train()
    assert bool((learner.theta != 0).any())
    before = learner.theta.clone()
    learner.set_extra_state({})
    trainer.evaluate()
    assert torch.equal(learner.theta, before)
    assert not learner.get_extra_state()  # evaluation recorded no likelihood-ratio terms


def test_a_baseline_keeps_the_mean_and_lowers_the_variance_of_the_estimate():
    # same draws with and without b: the difference is -b sum_n grad mu / mu per cycle, which
    # must average to zero
    plain, _, _ = run(online=False)
    centred, _, _ = run(online=False, baseline=0.05)
    assert (centred.reward_to_go_mean != 0).all()
    for name in ("Root", "A", "B"):
        p, c = per_learner_estimates(plain, name), per_learner_estimates(centred, name)
        diff = c - p
        se = diff.std(0) / len(diff) ** 0.5
        assert (diff.mean(0).abs() <= 4 * se + 1e-4).all(), (name, diff.mean(0), se)
        assert c.std(0).mean() < p.std(0).mean(), name


def test_a_baseline_needs_renewal_updates():
    with pytest.raises(ValueError, match="online=False"):
        PGConfig(baseline=0.1, online=True)


def test_the_state_baseline_is_on_by_default_where_it_applies():
    assert PGConfig().value_rate == 0.1 and not PGConfig().online  # (issue 33)
    for excluded in ({"online": True}, {"baseline": 0.1}, {"frozen": True}):
        assert PGConfig(**excluded).value_rate == 0.0, excluded
        with pytest.raises(ValueError, match="value_rate"):
            PGConfig(value_rate=0.1, **excluded)
    with pytest.raises(ValueError, match="value_rate"):
        PGConfig(value_rate=-0.1)
    graph = hierarchy()
    assert "value_table" in HPGRLLearner(graph, 2).state_dict()
    old_rule = HPGRLLearner(graph, 2, PGConfig(value_rate=0.0)).state_dict()
    assert "value_table" not in old_rule
    HPGRLLearner(graph, 2).load_state_dict(old_rule)  # (its V starts at 0)
