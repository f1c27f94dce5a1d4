import torch

from hrl_torch.policies import (
    TabularSoftmaxPolicy,
    TileGaussianPolicy,
    sample_categorical,
    squash,
    unsquash,
)
from hrl_torch.rng import BatchRNG
from hrl_torch.tiles import TileCoder


def _tabular(seed=0):
    torch.manual_seed(seed)
    policy = TabularSoftmaxPolicy(n_learners=3, n_states=5, n_actions=4)
    policy.theta.normal_()
    return policy


def test_tabular_score_equals_autograd_gradient_of_log_prob():
    policy = _tabular()
    learner = torch.tensor([0, 2, 2, 1, 0])
    state = torch.tensor([1, 4, 4, 0, 3])
    action = torch.tensor([3, 0, 2, 1, 1])
    available = torch.ones(5, 4, dtype=torch.bool)
    available[3, 2] = False
    theta = policy.theta.clone().requires_grad_(True)
    policy.theta = theta
    policy.log_prob(learner, state, action, available).sum().backward()
    index, value = policy.score(learner, state, action, available)
    ours = torch.zeros(theta.numel()).index_add_(0, index.flatten(), value.flatten().detach())
    assert torch.allclose(ours.view_as(theta), theta.grad, atol=1e-6)
    assert value[3, 2] == 0  # unavailable action: no gradient


def test_tabular_masked_probabilities():
    policy = _tabular()
    available = torch.tensor([[True, False, True, False]])
    p = policy.probs(torch.tensor([1]), torch.tensor([2]), available)
    assert torch.allclose(p.sum(-1), torch.ones(1))
    assert p[0, 1] == 0 and p[0, 3] == 0
    logits = policy.theta[1, 2, [0, 2]]
    assert torch.allclose(p[0, [0, 2]], torch.softmax(logits, 0))


def test_tabular_sampling_frequencies_match_probabilities():
    policy = _tabular()
    n = 40_000
    rng = BatchRNG([7], n, "policy")
    learner = torch.zeros(n, dtype=torch.long)
    state = torch.full((n,), 3)
    available = torch.tensor([True, True, False, True]).expand(n, 4)
    action = policy.sample(learner, state, rng.uniform(), available)
    freq = torch.bincount(action, minlength=4).float() / n
    expected = policy.probs(learner[:1], state[:1], available[:1])[0]
    assert freq[2] == 0
    assert torch.allclose(freq, expected, atol=0.01)


def test_sample_categorical_rounding_never_picks_zero_probability():
    probs = torch.tensor([[0.5, 0.5 - 1e-7, 0.0]])
    assert sample_categorical(probs, torch.tensor([0.9999999])).item() == 1


def test_population_rows_use_their_own_learner():
    policy = _tabular()
    policy.theta[1] = 0.0
    policy.theta[1, 2, 3] = 5.0
    p = policy.probs(torch.tensor([0, 1, 2]), torch.tensor([2, 2, 2]))
    assert torch.allclose(p[1], torch.softmax(torch.tensor([0.0, 0, 0, 5]), 0))
    assert torch.allclose(p[0], torch.softmax(policy.theta[0, 2], 0))
    assert torch.allclose(p[2], torch.softmax(policy.theta[2, 2], 0))
    index, _ = policy.score(torch.tensor([2]), torch.tensor([2]), torch.tensor([0]))
    assert torch.equal(index[0], torch.arange(4) + (2 * 5 + 2) * 4)


def _gaussian(n_learners=3):
    coder = TileCoder([0.0, -1.0], [1.0, 1.0], [4, 3], n_tilings=5)
    policy = TileGaussianPolicy(n_learners, coder, -15.0, 15.0, sigma=0.7)
    torch.manual_seed(1)
    policy.w.normal_()
    return policy


def test_gaussian_mean_is_normalised_tile_sum():
    policy = _gaussian()
    obs = torch.tensor([[0.3, 0.2], [0.9, -0.8]])
    learner = torch.tensor([2, 0])
    tiles = policy.tiles(obs)
    phi = torch.zeros(2, policy.n_features)
    phi.scatter_(1, tiles, 1.0)
    expected = (policy.w[learner] * phi).sum(-1) / phi.sum(-1)
    assert torch.allclose(policy.mean(learner, tiles), expected)


def test_gaussian_score_equals_autograd_gradient_of_log_prob():
    policy = _gaussian()
    obs = torch.rand(6, 2) * torch.tensor([1.0, 2.0]) - torch.tensor([0.0, 1.0])
    learner = torch.tensor([0, 1, 2, 2, 1, 0])
    tiles = policy.tiles(obs)
    _, u = policy.sample(learner, tiles, torch.randn(6))
    w = policy.w.clone().requires_grad_(True)
    policy.w = w
    policy.log_prob(learner, tiles, u.detach()).sum().backward()
    index, value = policy.score(learner, tiles, u.detach())
    ours = torch.zeros(w.numel()).index_add_(0, index.flatten(), value.flatten().detach())
    assert torch.allclose(ours.view_as(w), w.grad, atol=1e-6)
    assert ours.view_as(w).ne(0).sum() > 0


def test_gaussian_sampling_and_squashing():
    policy = _gaussian(n_learners=2)
    n = 20_000
    rng = BatchRNG([3, 4], n // 2, "policy")
    learner = torch.arange(n) // (n // 2)
    tiles = policy.tiles(torch.tensor([[0.5, 0.0]]).expand(n, 2))
    action, u = policy.sample(learner, tiles, rng.normal())
    assert action.min() > -15 and action.max() < 15
    assert torch.allclose(action, squash(u, -15.0, 15.0))
    assert torch.allclose(unsquash(action, -15.0, 15.0), u, atol=1e-3)
    for p in range(2):
        rows = learner == p
        mean = policy.w[p, tiles[0]].mean()
        assert abs(u[rows].mean() - mean) < 0.03
        assert abs(u[rows].std() - 0.7) < 0.03
