"""The MLP policy heads (hrl_torch.modules.neural_policies): autograd's scores, Equation 5.3's."""

import math
import warnings

import pytest
import torch

from hrl_torch.env.batched import BatchedEnv
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Primitive, Subtask
from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.modules.exploration import Greedy
from hrl_torch.modules.heads import PolicyInput
from hrl_torch.modules.neural_policies import MLPCategoricalPolicyHead, MLPGaussianPolicyHead
from hrl_torch.modules.policies import SoftmaxPolicyHead, TileGaussianPolicyHead, normals
from hrl_torch.modules.tables import TableBank
from hrl_torch.modules.tiles import TileCoder
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer
from tests.helpers import TableEnv

P, N = 3, 40
RANGE = {"action_low": -15.0, "action_high": 15.0}


def bound(head, seed=0):
    """``head`` bound to a bank of ``P`` learners holding random parameters."""
    one = torch.ones(1, dtype=torch.long)
    bank = TableBank(P, one * head.n_states, one * head.n_cols)
    head.bind(bank, 0)
    gen = torch.Generator().manual_seed(seed)
    bank.block(0).copy_(torch.randn(bank.block(0).shape, generator=gen))
    return bank


def rows(bank, n_features, seed=1):
    gen = torch.Generator().manual_seed(seed)
    learner = torch.arange(N) % P
    return PolicyInput(
        base=learner * bank.stride + bank.offset[0],
        state=torch.zeros(N, dtype=torch.long),
        features=torch.rand(N, n_features, generator=gen) * 10.0,
        available=torch.ones(N, 1, dtype=torch.bool),
        u=torch.rand(N, 3, generator=gen),
        step=0,
    )


@pytest.mark.parametrize("greedy", [False, True])
def test_autograd_score_equals_the_tile_coded_heads_hand_written_one(greedy):
    coder = TileCoder(low=[0.0, 0.0], high=[10.0, 10.0], resolution=[4, 3], n_tilings=3)
    tiles = TileGaussianPolicyHead("tiles", coder, sigma=0.7, action_low=-15.0, action_high=15.0)
    linear = MLPGaussianPolicyHead(
        "linear", 2, hidden=(), sigma=0.7, coder=coder, bias=False, **RANGE
    )
    assert linear.width == coder.n_features
    bank_t, bank_l = bound(tiles), bound(linear)
    bank_l.store.copy_(bank_t.store)  # the same weights
    inp = rows(bank_t, 2)
    hand = tiles.act(bank_t.store, inp, greedy)
    auto = linear.act(bank_l.store, inp, greedy)
    torch.testing.assert_close(auto.action, hand.action)
    dense = torch.zeros(N, bank_t.store.numel()).scatter_add_(1, hand.index, hand.score)
    mine = torch.zeros(N, bank_l.store.numel()).scatter_add_(1, auto.index, auto.score)
    torch.testing.assert_close(mine, dense, atol=1e-6, rtol=1e-5)
    if not greedy:
        assert hand.score.abs().sum() > 0  # (a score that is not zero everywhere)
    assert torch.equal(auto.greedy, hand.greedy)


def test_an_mlp_heads_batched_score_is_each_rows_own_gradient():
    head = MLPGaussianPolicyHead("mlp", 4, (8, 6), low=[0.0] * 4, high=[10.0] * 4, **RANGE)
    bank = bound(head)
    inp = rows(bank, 5)
    out = head.act(bank.store, inp, greedy=False)
    x = head.inputs(inp.features)
    pre = torch.logit((out.action - head.low) / (head.high - head.low))  # (unsquashed u)
    for r in (0, 7, 31):
        params = bank.store[out.index[r]].clone().requires_grad_(True)
        mean = head.mean(params[None], x[r : r + 1])[0]
        log_mu = -0.5 * ((pre[r] - mean) / head.sigma) ** 2
        (grad,) = torch.autograd.grad(log_mu, params)
        torch.testing.assert_close(out.score[r], grad, atol=1e-4, rtol=1e-3)


def test_bad_head_settings_are_refused():
    with pytest.raises(ValueError, match="sigma must be positive"):
        MLPGaussianPolicyHead("h", 2, sigma=0.0)
    with pytest.raises(ValueError, match="give low and high together"):
        MLPGaussianPolicyHead("h", 2, low=[0.0, 0.0])
    with pytest.raises(ValueError, match="low and high need 2 values each"):
        MLPGaussianPolicyHead("h", 2, low=[0.0], high=[1.0])


# ---------------------------------------------------------------- action vectors and categories
def test_a_two_entry_gaussians_score_is_the_analytic_gradient_of_its_log_density():
    """Linear mean ``A = x W + b``: ``d log N / d W[i, d] = x_i z_d / sigma`` with ``z`` the
    normals of the row's uniforms (the cosine and the sine of one Box-Muller pair)."""
    sigma, lo, hi = 0.5, torch.tensor([-1.0, -2.0]), torch.tensor([1.0, 4.0])
    head = MLPGaussianPolicyHead("g", 3, (), sigma, lo.tolist(), hi.tolist(), action_dim=2)
    assert head.n_uniforms == 3 and head.width == 3 * 2 + 2
    bank = bound(head)
    inp = rows(bank, 3)
    out = head.act(bank.store, inp, greedy=False)
    params = bank.store[out.index]  # [N, 8]: W (3 x 2, row-major), then b
    x = inp.features[:, :3]
    mean = torch.einsum("ni,nid->nd", x, params[:, :6].view(N, 3, 2)) + params[:, 6:]
    radius = torch.sqrt(-2 * torch.log(inp.u[:, 1]))
    z = torch.stack(
        [
            radius * torch.cos(2 * math.pi * inp.u[:, 2]),
            radius * torch.sin(2 * math.pi * inp.u[:, 2]),
        ],
        1,
    )
    torch.testing.assert_close(out.action, lo + (hi - lo) * torch.sigmoid(mean + sigma * z))
    hand = torch.cat([(x[:, :, None] * z[:, None, :] / sigma).reshape(N, 6), z / sigma], 1)
    torch.testing.assert_close(out.score, hand, atol=1e-4, rtol=1e-4)
    greedy = head.act(bank.store, inp, greedy=True)
    torch.testing.assert_close(greedy.action, lo + (hi - lo) * torch.sigmoid(mean))
    assert head.n_uniforms == 3
    assert MLPGaussianPolicyHead("g5", 3, action_dim=5, **RANGE).n_uniforms == 7


def test_a_linear_categorical_head_over_a_one_hot_is_the_tabular_softmax_with_autograd():
    """``hidden=()``, ``n_states=S``, no bias: the logits are ``theta[s, :]``, as the softmax
    head's, so the choices and the scores ``onehot(a) - mu(.|s)`` agree."""
    s, a = 5, 3
    soft = SoftmaxPolicyHead("soft", s, a, a)
    linear = MLPCategoricalPolicyHead("cat", 0, a, hidden=(), n_states=s, bias=False)
    bank_s, bank_c = bound(soft), bound(linear)
    bank_c.store.copy_(bank_s.store)
    gen = torch.Generator().manual_seed(3)
    inp = rows(bank_s, 1)
    inp.state = torch.randint(0, s, (N,), generator=gen)
    inp.available = torch.rand(N, a, generator=gen) < 0.7
    inp.available[:, 1] |= ~inp.available.any(1)  # (one available child at least)
    for greedy in (False, True):
        hand, auto = soft.act(bank_s.store, inp, greedy), linear.act(bank_c.store, inp, greedy)
        assert torch.equal(auto.child, hand.child) and torch.equal(auto.greedy, hand.greedy)
        assert bool(inp.available.gather(1, auto.child[:, None]).all())
        dense = torch.zeros(N, bank_s.store.numel()).scatter_add_(1, hand.index, hand.score)
        mine = torch.zeros(N, bank_c.store.numel()).scatter_add_(1, auto.index, auto.score)
        torch.testing.assert_close(mine, dense, atol=1e-6, rtol=1e-5)
    assert len(set(auto.child.tolist())) == a  # (every child chosen somewhere)


def test_mlp_heads_refuse_nodes_they_cannot_serve():
    graph = corridor()
    with pytest.raises(GraphError, match="has 2 children, the head 'A' 3 logits"):
        HPGRLLearner(graph, 1, heads={"A": MLPCategoricalPolicyHead("A", 0, 3, n_states=5)})
    with pytest.raises(GraphError, match="5 abstract states, the head 'A' a one-hot of 4"):
        HPGRLLearner(graph, 1, heads={"A": MLPCategoricalPolicyHead("A", 0, 2, n_states=4)})
    with pytest.raises(GraphError, match="acts with 2 numbers, the head 'Root' gives 1"):
        HPGRLLearner(reach_graph(), 1, heads={"Root": MLPGaussianPolicyHead("Root", 2, **RANGE)})
    with pytest.raises(ValueError, match="give one input encoding"):
        MLPCategoricalPolicyHead("c", 2, 2, low=[0, 0], high=[1, 1], n_states=3)
    with pytest.raises(ValueError, match="adam_lr must be positive"):
        MLPCategoricalPolicyHead("c", 0, 2, n_states=3, adam_lr=0.0)


def test_an_mlp_head_made_without_a_range_takes_the_envs_and_says_when_that_changed():
    from types import SimpleNamespace

    from hrl_torch.learners.action_range import use_action_bounds

    learner = HPGRLLearner(
        reach_graph(), 1, heads={"Root": MLPGaussianPolicyHead("Root", 2, action_dim=2)}
    )
    head = learner.heads["Root"]
    with pytest.raises(
        ValueError, match=r"defaulted to \(-15.0, 15.0\)\): give MLPGaussianPolicyHead"
    ):
        head.range()
    with pytest.raises(ValueError, match="no action range: give MLPGaussianPolicyHead"):
        use_action_bounds(learner, SimpleNamespace(action_bounds=None))
    with pytest.raises(ValueError, match="have 1 dimensions; the Gaussian head drives 2"):
        use_action_bounds(learner, SimpleNamespace(action_bounds=([-1.0], [1.0])))
    with pytest.warns(DeprecationWarning, match="no longer \\(-15.0, 15.0\\)"):
        use_action_bounds(learner, SimpleNamespace(action_bounds=([-1.0, 0.0], [1.0, 2.0])))
    assert head.range() == ((-1.0, 0.0), (1.0, 2.0))
    one = HPGRLLearner(gaussian_graph(1), 1, heads={"Root": MLPGaussianPolicyHead("Root", 2)})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (the old range: nothing changes, nothing said)
        use_action_bounds(one, SimpleNamespace(action_bounds=([-15.0], [15.0])))
    assert one.heads["Root"].range() == (-15.0, 15.0)


# ---------------------------------------------------------------- they learn
def corridor():
    from tests.learners.test_hpgrl import hierarchy

    return hierarchy()


class Pick(BatchedEnv):
    """``x`` uniform in ``[0, 1]^2``; three actions, reward 1 for action ``floor(3 x_0)``, else
    0; a new ``x`` every step; episodes of 3 steps."""

    state_keys = ("x", "t")

    def __init__(self, seeds, envs_per_learner):
        super().__init__(seeds, envs_per_learner, 3, None)
        self.x = torch.zeros(self.batch_size, 2)
        self.t = torch.zeros(self.batch_size, dtype=torch.long)

    def _reset_rows(self, mask):
        self.x = torch.where(mask[:, None], self.rng.uniform(2), self.x)
        self.t = torch.where(mask, 0, self.t)

    def _step_all(self, action):
        reward = (action == (3 * self.x[:, 0]).long().clamp_max(2)).float()
        self.x = self.rng.uniform(2)
        self.t = self.t + 1
        return reward, torch.ones_like(reward), self.t >= 3

    def _observe(self):
        return {"observation": self.x.clone()}


def probe_input(learner, x: torch.Tensor, n_children: int) -> PolicyInput:
    """200 probes at features ``x``: the first 100 for learner 0, the rest for learner 1."""
    return PolicyInput(
        base=torch.tensor([0, learner.total]).repeat_interleave(100),
        state=torch.zeros(200, dtype=torch.long),
        features=x,
        available=torch.ones(200, n_children, dtype=torch.bool),
        u=torch.rand(200, 3),
        step=0,
    )


def test_a_categorical_mlp_head_learns_which_child_each_feature_wants():
    """Flat PGRL with an MLP softmax (16 tanh units over scaled features, Adam) on ``Pick``:
    the greedy choice is right for 0.40 and 0.35 of the probes untrained (every logit 0: the
    first child), for more than 0.7 after 2,000 steps (measured: 0.83 and 0.83)."""
    root = Subtask("Root", ["a0", "a1", "a2"], features=lambda o: o["observation"], n_features=2)
    graph = TaskGraph("Root", [root, *(Primitive(f"a{k}", k) for k in range(3))], 3)
    head = MLPCategoricalPolicyHead("Root", 2, 3, (16,), low=[0, 0], high=[1, 1], adam_lr=0.03)
    # (Algorithm 3's every-step rule, as measured; PGConfig's default renewal rule with the state
    # baseline, which over an MLP's dense parameters is one running mean, gave 0.71 and 0.69)
    pg = PGConfig(trace_len=4, online=True)
    learner = HPGRLLearner(graph, 2, pg, heads={"Root": head})
    config = TrainConfig(steps=2_000, eval_every=0, progress=False)
    trainer = Trainer(Pick([0, 1], 32), graph, learner, Greedy(), config)
    x = torch.rand(200, 2, generator=torch.Generator().manual_seed(5))
    inp = probe_input(learner, x, n_children=3)

    def right() -> list[float]:
        child = head.act(learner.theta, inp, greedy=True).child
        return (child == (3 * x[:, 0]).long()).float().view(2, -1).mean(1).tolist()

    untrained = right()
    trainer.train()
    trained = right()
    assert max(untrained) < 0.45
    assert min(trained) > 0.7, trained


@pytest.mark.slow
def test_a_categorical_mlp_head_learns_the_corridor():
    """test_custom_head's corridor with MLP softmaxes (16 tanh units over a one-hot) at every
    node, two levels: the greedy return rises from 0.61 to more than 10 (of at most 15).
    (Fast twin: the one-level ``Pick`` above.)"""
    from tests.learners.test_hpgrl import NEXT, REWARD, STARTS, TERMINAL
    from tests.learners.test_hpgrl import N as S
    from tests.test_custom_head import greedy_return

    graph = corridor()
    heads = {k: MLPCategoricalPolicyHead(k, 0, 2, (16,), n_states=S) for k in ("Root", "A", "B")}
    learner = HPGRLLearner(graph, 2, PGConfig(alpha=0.05, trace_len=400), heads=heads)
    terminal = torch.arange(S) == TERMINAL
    env = TableEnv(NEXT, REWARD, terminal, STARTS, [0, 1], 16, max_episode_steps=50)
    eval_env = TableEnv(NEXT, REWARD, terminal, STARTS, [7, 7], 40, max_episode_steps=30)
    config = TrainConfig(steps=3_000, eval_every=0, progress=False)
    trainer = Trainer(env, graph, learner, Greedy(), config, eval_env=eval_env)
    untrained = greedy_return(trainer)
    trainer.train()
    trained = greedy_return(trainer)
    assert untrained < 2.0
    assert trained > 10.0, (untrained, trained)


class Reach2(BatchedEnv):
    """``x`` uniform in ``[0, 1]^2``; a two-entry action in ``[-15, 15]^2``, reward
    ``-sum_d ((a_d - (10 x_d - 5)) / 5)^2``; a new ``x`` every step; episodes of 3 steps."""

    state_keys = ("x", "t")
    action_bounds = ([-15.0, -15.0], [15.0, 15.0])

    def __init__(self, seeds, envs_per_learner):
        super().__init__(seeds, envs_per_learner, None)
        self.x = torch.zeros(self.batch_size, 2)
        self.t = torch.zeros(self.batch_size, dtype=torch.long)

    def _reset_rows(self, mask):
        self.x = torch.where(mask[:, None], self.rng.uniform(2), self.x)
        self.t = torch.where(mask, 0, self.t)

    def _step_all(self, action):
        reward = -(((action - (10 * self.x - 5)) / 5) ** 2).sum(1)
        self.x = self.rng.uniform(2)
        self.t = self.t + 1
        return reward, torch.ones_like(reward), self.t >= 3

    def _observe(self):
        return {"observation": self.x.clone()}


def gaussian_graph(action_dim: int) -> TaskGraph:
    root = Subtask("Root", ["act"], features=lambda o: o["observation"], n_features=2, n_states=1)
    return TaskGraph("Root", [root, Primitive("act", action_dim=action_dim)])


def reach_graph() -> TaskGraph:
    return gaussian_graph(2)


def test_a_two_entry_mlp_gaussian_learns_to_reach():
    """Flat PGRL with a 2-entry MLP Gaussian (16 tanh units, Adam): the greedy action's mean
    error per entry falls from 2.5 (the untrained mean action 0) to under 1.25 for both
    learners (measured: 0.80 and 0.42)."""
    head = MLPGaussianPolicyHead(
        "Root", 2, (16,), 0.3, low=[0, 0], high=[1, 1], action_dim=2, adam_lr=0.01
    )
    learner = HPGRLLearner(reach_graph(), 2, PGConfig(trace_len=4), heads={"Root": head})
    config = TrainConfig(steps=1_500, eval_every=0, progress=False)
    trainer = Trainer(Reach2([0, 1], 32), learner.graph, learner, Greedy(), config)
    x = torch.rand(200, 2, generator=torch.Generator().manual_seed(5))
    inp = probe_input(learner, x, n_children=1)

    def error() -> list[float]:
        action = head.act(learner.theta, inp, greedy=True).action
        return (action - (10 * x - 5)).abs().view(2, -1).mean(1).tolist()

    trainer.train()  # (the head takes the env's 2-entry range at the start)
    assert head.range() == ((-15.0, -15.0), (15.0, 15.0))
    trained = error()
    learner.params.store.zero_()  # (untrained: every weight 0, the mean action 0)
    assert min(error()) > 2.0
    assert max(trained) < 1.25, trained


def test_mlp_heads_log_their_weights_norm_not_tile_statistics():
    heads = {
        "Root": MLPGaussianPolicyHead("Root", 2, (4,), 0.5, action_dim=2, **RANGE),
    }
    learner = HPGRLLearner(reach_graph(), 3, heads=heads)
    out = learner.log_scalars(0)
    assert "hrl/Root/policy_mean" not in out and "hrl/Root/policy_spread" not in out
    theta0 = heads["Root"].theta0
    assert out["hrl/Root/weight_norm"] == pytest.approx([float(theta0.norm())] * 3)
    assert out["hrl/Root/policy_sigma"] == [0.5] * 3


def test_a_five_entry_gaussian_draws_seven_uniforms_and_acts_with_five_numbers():
    from tensordict import TensorDict

    from hrl_torch.common.rng import BatchRNG

    head = MLPGaussianPolicyHead("Root", 2, (4,), action_dim=5, **RANGE)
    learner = HPGRLLearner(gaussian_graph(5), 2, heads={"Root": head})
    assert learner.n_uniforms == 7  # (1 + 3 Box-Muller pairs)
    rng = BatchRNG([0, 1], 4, "draws")
    assert learner.make_policy(Greedy(), rng).draws.levels.shape[-1] == 7
    obs = TensorDict({"observation": torch.rand(8, 2)}, batch_size=[8])
    ctx = learner.graph.context(obs, torch.arange(8) // 4)
    u = rng.uniform(7)
    out = learner.select(torch.zeros(8, dtype=torch.long), ctx, ctx.available[:, 0], u)
    assert out.action.shape == (8, 5)
    z = torch.logit((out.action + 15.0) / 30.0)  # (the mean is 0: the noise itself)
    torch.testing.assert_close(z, normals(u, 5), atol=1e-3, rtol=1e-3)
    assert len({round(float(v), 3) for v in z[0]}) == 5  # (five different numbers)
