"""Likelihood-ratio scores and gradient estimates on the path the PG learners run.

HPGRL, flat PGRL, the hybrid's PG part and the actor-critic all choose through
``HPGRLLearner.select``: it routes each row to its node's policy head (``head.act``), keeps the
head's likelihood-ratio term ``grad mu(a|s) / mu(a|s)`` as the row's pending choice, and
``update`` moves it into the invocation's eligibility and applies Equation 5.2/5.3 (or the
actor's step). These tests go through that path (``select``, the executor and ``update``;
``tests/test_policies.py`` calls the heads directly) and compare what it stores and applies
with torch.autograd of ``log mu(a|s)`` of the action actually taken: the child slot ``select``
returned, and for the squashed Gaussian the sample before the squash, ``u = unsquash(action)``
of the action the env received (the score is ``(u - A) / sigma^2`` per active tile; the
squash does not depend on ``theta``). The autograd side is written out here from the
parameters' layout (each group's block of ``theta``) and the tile coder, not from the heads.
"""

import math

import pytest
import torch
from tensordict import TensorDict

from hrl_torch.common.rng import BatchRNG
from hrl_torch.env.batched import BatchedEnv
from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners.pg import ActorCriticLearner, HPGRLLearner, PGConfig, PGPolicy
from hrl_torch.modules.policies import squash, unsquash
from hrl_torch.modules.tiles import TileCoder
from hrl_torch.training.agent import with_values
from tests.helpers import TableEnv

LOW, HIGH = -15.0, 15.0  # the action range these tests give their Gaussian heads
RANGE = {"action_low": LOW, "action_high": HIGH}

# ---------------------------------------------------------------- a finite MDP for softmax nodes
N_STATES, N_ACTIONS = 6, 3
NEXT = torch.tensor([[1, 2, 0], [3, 0, 4], [4, 5, 1], [5, 1, 2], [0, 3, 5], [2, 4, 3]])
REWARD = torch.tensor(
    [
        [-1.0, 0.5, 2.0],
        [0.3, -0.7, 1.0],
        [1.5, -2.0, 0.2],
        [-0.4, 0.9, -1.3],
        [0.8, 0.1, -0.6],
        [2.5, -1.1, 0.4],
    ]
)
TERMINAL = torch.tensor([False, False, False, False, False, True])
STARTS = torch.tensor([0, 1, 2, 3, 4])
# the children each state allows (a masked softmax: unavailable children get no score)
ALLOWED = torch.tensor(
    [[1, 1, 1], [1, 0, 1], [0, 1, 1], [1, 1, 0], [1, 1, 1], [1, 1, 1]], dtype=torch.bool
)


def state(o):
    return o["observation"]


def table_env(seeds, envs):
    return TableEnv(NEXT, REWARD, TERMINAL, STARTS, seeds, envs, max_episode_steps=12)


def primitives():
    return [Primitive(f"a{j}", j) for j in range(N_ACTIONS)]


def two_level_graph() -> TaskGraph:
    """Root (2 children, padded to 3 columns) -> A (3 primitives, masked), B (2 primitives)."""
    root = Subtask("Root", ["A", "B"], n_states=N_STATES, abstract=state)
    a = Subtask(
        "A",
        ["a0", "a1", "a2"],
        n_states=N_STATES,
        abstract=state,
        terminated=lambda o: o["observation"] >= 4,
        child_mask=lambda o: ALLOWED[o["observation"]],
    )
    b = Subtask(
        "B",
        ["a2", "a0"],
        n_states=3,
        abstract=lambda o: o["observation"] % 3,
        terminated=lambda o: o["observation"] <= 1,
    )
    return TaskGraph("Root", [root, a, b, *primitives()], n_actions=N_ACTIONS)


def flat_softmax_graph() -> TaskGraph:
    root = Subtask(
        "Root",
        ["a0", "a1", "a2"],
        n_states=N_STATES,
        abstract=state,
        child_mask=lambda o: ALLOWED[o["observation"]],
    )
    return TaskGraph("Root", [root, *primitives()], n_actions=N_ACTIONS)


def randomize(learner, scale=1.0, seed=0):
    g = torch.Generator().manual_seed(seed)
    n = learner.sentinel
    learner.theta[:n] = scale * torch.randn(n, generator=g)
    return learner


def dense(learner, index, value):
    """A sparse likelihood-ratio term ``(index [K], value [K])`` as a dense ``[P * total]``."""
    out = torch.zeros(learner.theta.numel(), dtype=torch.float64)
    out.index_add_(0, index, value.double())
    return out[: learner.sentinel]


def leaf(learner, values=None):
    """``theta`` (or ``values`` in its layout) as a float64 leaf for autograd, and a function
    reading a group's block of it."""
    values = learner.theta if values is None else values
    theta = values.detach().double().clone().requires_grad_(True)
    flat = theta[: learner.sentinel].view(learner.n_learners, learner.total)

    def block(group, p):
        k = learner.group_names.index(group)
        head = learner.heads[group]
        start = int(learner.params.offset[k])
        return flat[p, start : start + head.n_states * head.n_cols].view(head.n_states, -1)

    return theta, block


def grad(theta, value):
    (g,) = torch.autograd.grad(value, theta, retain_graph=True)
    return g[:-1]


def softmax_log_prob(block, group, p, s, child, available):
    """``log mu(child | s)`` of learner ``p``'s softmax node, from the raw parameters."""
    logits = block(group, p)[s, : available.shape[0]]
    logits = logits.masked_fill(~available, -math.inf)
    return torch.log_softmax(logits, -1)[child]


# ---------------------------------------------------------------- a continuous task: Gaussian nodes
class Reach(BatchedEnv):
    """Continuous features ``x`` in ``[0, 1]^2``; action ``a`` in ``[-15, 15]``, reward
    ``-|a - (20 x_0 - 10)| / 5``; a new ``x`` every step; episodes of 3 steps."""

    state_keys = ("x", "t")
    action_bounds = ([LOW], [HIGH])

    def __init__(self, seeds, envs_per_learner):
        super().__init__(seeds, envs_per_learner, None)
        self.x = torch.zeros(self.batch_size, 2)
        self.t = torch.zeros(self.batch_size, dtype=torch.long)

    def _reset_rows(self, mask):
        fresh = self.rng.uniform(2)
        self.x = torch.where(mask[:, None], fresh, self.x)
        self.t = torch.where(mask, 0, self.t)

    def _step_all(self, action):
        a = action.reshape(-1)
        reward = -(a - (20 * self.x[:, 0] - 10)).abs() / 5
        self.x = self.rng.uniform(2)
        self.t = self.t + 1
        return reward, torch.ones_like(reward), self.t >= 3

    def _observe(self):
        return {"observation": self.x.clone()}


def coder():
    return TileCoder([0.0, 0.0], [1.0, 1.0], [4, 3], n_tilings=3)


def gaussian_graph() -> TaskGraph:
    root = Subtask("Root", ["act"], features=lambda o: o["observation"], n_features=2, n_states=1)
    return TaskGraph("Root", [root, Primitive("act", action_dim=1)])


def gaussian_log_prob(theta_block, tiles, u, sigma):
    """``log N(u; A, sigma^2)`` with ``A`` the mean of the active tiles' weights."""
    mean = theta_block[tiles].mean()
    return -0.5 * ((u - mean) / sigma) ** 2 - math.log(sigma * math.sqrt(2 * math.pi))


# ---------------------------------------------------------------- scores stored by select
@pytest.mark.parametrize("node", ["Root", "A", "B"])
def test_select_stores_the_softmax_score_of_the_chosen_child(node):
    graph = two_level_graph()
    learner = randomize(HPGRLLearner(graph, 2), scale=1.5)
    e = 12
    rows = torch.arange(2 * e) // e
    obs = TensorDict({"observation": torch.arange(2 * e) % N_STATES}, batch_size=[2 * e])
    ctx = graph.context(obs, rows)
    inst = next(k for k in range(graph.n_instances) if graph.instance_path(k).endswith(node))
    k = graph.index[node]
    available = ctx.available[:, k]
    u = BatchRNG([0, 1], e, "scores").uniform(3)
    out = learner.select(torch.full((2 * e,), inst), ctx, available, u)
    child, action = out.child, out.action
    assert action is None
    index, value = out.score_index, out.score_value
    theta, block = leaf(learner)
    n_children = len(graph.nodes[k].children_names)
    seen = set()
    for b in range(2 * e):
        assert bool(available[b, child[b]])  # the chosen child is available
        s = int(ctx.abstract[b, k])
        ok = available[b, :n_children]
        log_p = softmax_log_prob(block, node, int(rows[b]), s, int(child[b]), ok)
        expected = grad(theta, log_p)
        assert torch.allclose(dense(learner, index[b], value[b]), expected, atol=1e-6), b
        seen.add((int(rows[b]), s, int(child[b])))
    assert len(seen) >= 8  # several learners, states and children


def test_select_stores_the_gaussian_score_of_the_unsquashed_sample():
    graph = gaussian_graph()
    sigma = 0.7
    learner = randomize(HPGRLLearner(graph, 2, PGConfig(sigma=sigma, **RANGE), coder=coder()), 2.0)
    e = 16
    env = Reach([3, 4], e)
    rows = env.learner_of_row()
    ctx = graph.context(env.reset(), rows)
    u = BatchRNG([3, 4], e, "scores").uniform(3)
    available = ctx.available[:, 0]
    out = learner.select(torch.zeros(2 * e, dtype=torch.long), ctx, available, u)
    action, index, value = out.action, out.score_index, out.score_value
    pre = unsquash(action[:, 0].double(), LOW, HIGH)  # the sample before the squash
    # the squash matters: the action differs from the sample by far more than the tolerance
    assert (action[:, 0].double() - pre).abs().max() > 1.0
    theta, block = leaf(learner)
    tiles = coder()(ctx.obs["observation"])
    for b in range(2 * e):
        p = int(rows[b])
        log_p = gaussian_log_prob(block("Root", p)[0], tiles[b], pre[b], sigma)
        expected = grad(theta, log_p)
        ours = dense(learner, index[b], value[b])
        assert torch.allclose(ours, expected, atol=2e-4), (b, ours[ours != 0], pre[b])
        assert expected.abs().max() > 1e-2  # a nonzero score at the active tiles


# ---------------------------------------------------------------- gradient estimates through update
def run_frozen(graph, learner, env, steps):
    """Train a frozen PG learner; record every step ``(obs, action, reward, done, is_init)``.

    ``obs`` is what the action was chosen at; a row's step with ``is_init`` only reset it (its
    action was not a choice of the policy).
    """
    executor = HierarchicalExecutor(
        graph, env.batch_size, env.envs_per_learner, score_width=learner.score_width
    )
    policy = PGPolicy(learner, BatchRNG(env.seeds, env.envs_per_learner, "explore"))
    rows = env.learner_of_row()
    ctx = graph.context(env.reset(), rows)
    action = executor.act(ctx, policy, 0)
    trace = []
    for _ in range(steps):
        obs = ctx.obs
        td = env.step(action)
        done = td["terminated"] | td["truncated"]
        trace.append((obs, action.clone(), td["reward"], done, td["is_init"]))
        ctx = graph.context(td, rows)
        learner.update(with_values(executor.observe(td, ctx), ctx), 0)
        action = executor.act(ctx, policy, 0)
    return trace


def estimate(trace, log_prob, online):
    """``sum_n G_n log mu(a_n | s_n)`` over every row's episodes, ``G_n`` the reward-to-go.

    Renewal updates count the finished episodes only; online updates (line 16 every step)
    also the rewards seen so far in the running ones.
    """
    total = 0.0

    def add(episode):
        nonlocal total
        to_go = 0.0
        for lp, r in reversed(episode):
            to_go += r
            total = total + to_go * lp

    for b in range(trace[0][2].shape[0]):
        episode = []
        for obs, action, reward, done, is_init in trace:
            if bool(is_init[b]):
                continue
            episode.append((log_prob(obs, action, b), float(reward[b])))
            if bool(done[b]):
                add(episode)
                episode = []
        if online:
            add(episode)
    return total


@pytest.mark.parametrize("online", [False, True])
def test_flat_softmax_gradient_estimate_is_the_autograd_gradient(online):
    graph = flat_softmax_graph()
    config = PGConfig(frozen=True, online=online, trace_len=16, **RANGE)
    learner = randomize(HPGRLLearner(graph, 2, config))
    env = table_env([5, 6], 4)
    trace = run_frozen(graph, learner, env, 30)
    rows = env.learner_of_row()
    theta, block = leaf(learner)

    def log_prob(obs, action, b):
        s = int(obs["observation"][b])
        return softmax_log_prob(block, "Root", int(rows[b]), s, int(action[b]), ALLOWED[s])

    expected = grad(theta, estimate(trace, log_prob, online))
    assert int(learner.cycles.sum()) >= 10  # episodes ended (some by the time limit)
    assert expected.abs().max() > 0.5
    ours = learner.grad_sum[:-1].double()
    assert torch.allclose(ours, expected, atol=1e-4), (ours - expected).abs().max()


@pytest.mark.parametrize("online", [False, True])
def test_flat_gaussian_gradient_estimate_is_the_autograd_gradient(online):
    graph = gaussian_graph()
    sigma = 0.8
    config = PGConfig(frozen=True, online=online, sigma=sigma, trace_len=4, **RANGE)
    learner = randomize(HPGRLLearner(graph, 2, config, coder=coder()), 2.0)
    env = Reach([7, 8], 4)
    trace = run_frozen(graph, learner, env, 12)
    rows = env.learner_of_row()
    theta, block = leaf(learner)
    tile_coder = coder()

    def log_prob(obs, action, b):
        tiles = tile_coder(obs["observation"][b : b + 1])[0]
        pre = unsquash(action[b, 0].double(), LOW, HIGH)
        return gaussian_log_prob(block("Root", int(rows[b]))[0], tiles, pre, sigma)

    expected = grad(theta, estimate(trace, log_prob, online))
    assert expected.abs().max() > 0.5
    ours = learner.grad_sum[:-1].double()
    assert torch.allclose(ours, expected, atol=2e-3), (ours - expected).abs().max()


def test_actor_critic_steps_along_the_autograd_score_weighted_by_the_advantage():
    # one step: theta += beta (Q(s, a) - Q(s, squash(A(s)))) grad log mu(a|s), random critic
    graph = gaussian_graph()
    sigma, beta = 0.9, 0.05
    critic_coder = TileCoder([0.0, 0.0, LOW], [1.0, 1.0, HIGH], [3, 3, 5], n_tilings=4)
    config = PGConfig(alpha=beta, sigma=sigma, **RANGE)
    learner = randomize(ActorCriticLearner(graph, 2, coder(), critic_coder, config), 2.0)
    g = torch.Generator().manual_seed(1)
    learner.critic.w[:-1] = torch.randn(learner.critic.w.numel() - 1, generator=g)
    e = 8
    env = Reach([1, 2], e)
    executor = HierarchicalExecutor(graph, env.batch_size, e, score_width=learner.score_width)
    policy = PGPolicy(learner, BatchRNG([1, 2], e, "explore"))
    rows = env.learner_of_row()
    ctx = graph.context(env.reset(), rows)
    features = ctx.obs["observation"].clone()
    action = executor.act(ctx, policy, 0)
    before, critic = learner.theta.clone(), learner.critic.w.clone()
    td = env.step(action)
    ctx = graph.context(td, rows)
    learner.update(with_values(executor.observe(td, ctx), ctx), 0)
    # the expected step, from the parameters before it
    theta, block = leaf(learner, before)
    tiles = coder()(features)
    pre = unsquash(action[:, 0].double(), LOW, HIGH)
    per_learner = learner.critic.n_features

    def q(a):
        x = torch.cat([features, a.reshape(-1, 1).float()], 1)
        return critic[critic_coder(x) + rows[:, None] * per_learner].double().mean(-1)

    mean = torch.stack([block("Root", int(rows[b]))[0][tiles[b]].mean() for b in range(2 * e)])
    advantage = q(action[:, 0]) - q(squash(mean.detach(), LOW, HIGH))
    assert (advantage.abs() > 1e-3).sum() >= 10  # same critic tiles: no advantage
    objective = sum(
        advantage[b] * gaussian_log_prob(block("Root", int(rows[b]))[0], tiles[b], pre[b], sigma)
        for b in range(2 * e)
    )
    expected = beta * grad(theta, objective)
    step = (learner.theta - before)[:-1].double()
    assert expected.abs().max() > 1e-2
    assert torch.allclose(step, expected, atol=1e-4), (step - expected).abs().max()


def test_the_action_range_comes_from_the_config_or_the_env_never_a_silent_default():
    from types import SimpleNamespace

    from hrl_torch.learners.action_range import use_action_bounds

    graph = gaussian_graph()
    bare = HPGRLLearner(graph, 1, PGConfig(), coder=coder())
    head = bare.heads["Root"]
    assert head.low is None  # nothing given: no +-15
    with pytest.raises(ValueError, match="no action range: give PGConfig"):
        use_action_bounds(bare, SimpleNamespace(action_bounds=None))
    use_action_bounds(bare, SimpleNamespace(action_bounds=([-2.0], [3.0])))
    assert head.range() == (-2.0, 3.0)
    given = HPGRLLearner(graph, 1, PGConfig(**RANGE), coder=coder())
    use_action_bounds(given, SimpleNamespace(action_bounds=([-2.0], [3.0])))  # the config wins
    assert given.heads["Root"].range() == (LOW, HIGH)
    with pytest.raises(ValueError, match="2 dimensions"):
        use_action_bounds(
            HPGRLLearner(graph, 1, PGConfig(), coder=coder()),
            SimpleNamespace(action_bounds=([-1.0, -1.0], [1.0, 1.0])),
        )
