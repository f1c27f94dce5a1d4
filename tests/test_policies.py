"""The policy heads the PG learners run: choices, probabilities and likelihood-ratio scores."""

import math

import torch

from hrl_torch.common.rng import BatchRNG
from hrl_torch.modules.heads import PolicyInput
from hrl_torch.modules.policies import (
    SoftmaxPolicyHead,
    TileGaussianPolicyHead,
    gaussian_log_prob,
    sample_categorical,
    squash,
    unsquash,
)
from hrl_torch.modules.tables import TableBank
from hrl_torch.modules.tiles import TileCoder


def bind(head, n_learners, seed=0):
    """The head's parameters in a flat bank of its own, filled with normals."""
    bank = TableBank(n_learners, torch.tensor([head.n_states]), torch.tensor([head.n_cols]))
    head.bind(bank, 0)
    torch.manual_seed(seed)
    bank.data.normal_()
    return bank


def softmax_setup(n=5):
    head = SoftmaxPolicyHead("S", n_states=5, n_children=3, stride=4)
    bank = bind(head, 3)
    learner = torch.tensor([0, 2, 2, 1, 0])[:n]
    state = torch.tensor([1, 4, 4, 0, 3])[:n]
    available = torch.tensor([True, True, True, False]).repeat(n, 1)  # slot 3: padding
    available[min(3, n - 1), 1] = False
    return head, bank, learner, state, available


def test_softmax_score_equals_autograd_gradient_of_log_prob():
    head, bank, learner, state, available = softmax_setup()
    u = BatchRNG([1], 5, "u").uniform(3)
    out = head.act(
        bank.store, PolicyInput(learner * bank.total, state, None, available, u, 0), False
    )
    theta = bank.store.clone().requires_grad_(True)
    view = theta[:-1].view(3, 5, 4)[learner, state]
    log_p = torch.log_softmax(view.masked_fill(~available, -math.inf), -1)
    log_p.gather(1, out.child[:, None]).sum().backward()
    ours = torch.zeros_like(theta).index_add_(0, out.index.flatten(), out.score.flatten())
    assert torch.allclose(ours[:-1], theta.grad[:-1], atol=1e-6)
    assert bool((out.score[~available] == 0).all())  # unavailable children: no gradient
    assert bool(available.gather(1, out.child[:, None]).all())


def test_softmax_greedy_takes_the_mode_and_population_rows_read_their_own_block():
    head, bank, learner, state, available = softmax_setup()
    bank.data[1] = 0.0
    bank.data[1].view(5, 4)[0, 2] = 5.0
    u = torch.zeros(5, 3)
    out = head.act(
        bank.store, PolicyInput(learner * bank.total, state, None, available, u, 0), True
    )
    assert int(out.child[3]) == 2 and bool(out.greedy.all())
    blocks = bank.block(0)
    expected = blocks[learner, state].masked_fill(~available, -math.inf).argmax(-1)
    assert torch.equal(out.child, expected)


def test_softmax_sampling_frequencies_match_probabilities():
    head, bank, _, _, _ = softmax_setup(1)
    n = 40_000
    available = torch.tensor([True, False, True, True]).expand(n, 4)
    base, state = torch.zeros(n, dtype=torch.long), torch.full((n,), 3)
    u = BatchRNG([7], n, "policy").uniform(3)
    out = head.act(bank.store, PolicyInput(base, state, None, available, u, 0), False)
    freq = torch.bincount(out.child, minlength=4).float() / n
    probs = torch.softmax(bank.block(0)[0, 3].masked_fill(~available[0], -math.inf), 0)
    assert freq[1] == 0
    assert torch.allclose(freq, probs, atol=0.01)


def test_sample_categorical_rounding_never_picks_zero_probability():
    probs = torch.tensor([[0.5, 0.5 - 1e-7, 0.0]])
    assert sample_categorical(probs, torch.tensor([0.9999999])).item() == 1


def gaussian_setup(n_learners=3):
    coder = TileCoder([0.0, -1.0], [1.0, 1.0], [4, 3], n_tilings=5)
    head = TileGaussianPolicyHead("G", coder, sigma=0.7, action_low=-15.0, action_high=15.0)
    return head, bind(head, n_learners, seed=1)


def test_gaussian_mean_is_the_normalised_tile_sum():
    head, bank = gaussian_setup()
    feats = torch.tensor([[0.3, 0.2], [0.9, -0.8]])
    learner = torch.tensor([2, 0])
    phi = torch.zeros(2, head.coder.n_features).scatter_(1, head.coder(feats), 1.0)
    expected = (bank.block(0)[learner, 0] * phi).sum(-1) / phi.sum(-1)
    _, mean = head.mean(bank.store, learner * bank.total, feats)
    assert torch.allclose(mean, expected)


def test_gaussian_score_of_the_squashed_action_equals_autograd_of_the_pre_squash_density():
    # the score must be taken for u = unsquash(action), the sample before the squashing
    head, bank = gaussian_setup()
    feats = torch.rand(6, 2) * torch.tensor([1.0, 2.0]) - torch.tensor([0.0, 1.0])
    learner = torch.tensor([0, 1, 2, 2, 1, 0])
    u = BatchRNG([2], 6, "u").uniform(3)
    available = torch.ones(6, 1, dtype=torch.bool)
    inp = PolicyInput(
        learner * bank.total, torch.zeros(6, dtype=torch.long), feats, available, u, 0
    )
    out = head.act(bank.store, inp, False)
    pre = unsquash(out.action.double(), -15.0, 15.0).float()
    theta = bank.store.clone().requires_grad_(True)
    _, mean = head.mean(theta, learner * bank.total, feats)
    gaussian_log_prob(pre, mean, 0.7).sum().backward()
    ours = torch.zeros_like(theta).index_add_(0, out.index.flatten(), out.score.flatten())
    assert torch.allclose(ours[:-1], theta.grad[:-1], atol=1e-3)
    assert ours.ne(0).sum() > 0


def test_gaussian_sampling_and_squashing():
    head, bank = gaussian_setup(n_learners=2)
    n = 20_000
    learner = torch.arange(n) // (n // 2)
    feats = torch.tensor([[0.5, 0.0]]).expand(n, 2)
    u = BatchRNG([3, 4], n // 2, "policy").uniform(3)
    available = torch.ones(n, 1, dtype=torch.bool)
    inp = PolicyInput(
        learner * bank.total, torch.zeros(n, dtype=torch.long), feats, available, u, 0
    )
    out = head.act(bank.store, inp, False)
    assert out.action.min() > -15 and out.action.max() < 15
    pre = unsquash(out.action, -15.0, 15.0)
    assert torch.allclose(squash(pre, -15.0, 15.0), out.action, atol=1e-5)
    tiles, mean = head.mean(bank.store, learner * bank.total, feats)
    for p in range(2):
        rows = learner == p
        assert abs(pre[rows].mean() - mean[rows][0]) < 0.03
        assert abs(pre[rows].std() - 0.7) < 0.03
    greedy = head.act(bank.store, inp, True)
    assert torch.allclose(greedy.action, squash(mean, -15.0, 15.0))
    assert bool((greedy.score == 0).all())
