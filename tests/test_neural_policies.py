"""The MLP Gaussian head (hrl_torch.modules.neural_policies): autograd's score is Equation 5.3's."""

import pytest
import torch

from hrl_torch.modules.heads import PolicyInput
from hrl_torch.modules.neural_policies import MLPGaussianPolicyHead
from hrl_torch.modules.policies import TileGaussianPolicyHead
from hrl_torch.modules.tables import TableBank
from hrl_torch.modules.tiles import TileCoder

P, N = 3, 40


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
    linear = MLPGaussianPolicyHead("linear", 2, hidden=(), sigma=0.7, coder=coder, bias=False)
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
    head = MLPGaussianPolicyHead("mlp", 4, hidden=(8, 6), low=[0.0] * 4, high=[10.0] * 4)
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
