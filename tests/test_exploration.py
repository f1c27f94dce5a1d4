import torch

from hrl_torch.common.rng import BatchRNG
from hrl_torch.modules.exploration import (
    Boltzmann,
    EpsilonGreedy,
    Greedy,
    masked_argmax,
    uniform_choice,
    uniforms_needed,
)
from hrl_torch.modules.schedules import Constant, Exponential, Linear


def test_schedules():
    assert Linear(1.0, 0.1, 100)(0) == 1.0 and Linear(1.0, 0.1, 100)(50) == 0.55
    assert Linear(1.0, 0.1, 100)(1000) == 0.1
    assert Exponential(1.0, 0.5, every=10, minimum=0.2)(25) == 0.25
    assert Exponential(1.0, 0.5, every=10, minimum=0.2)(100) == 0.2
    assert Constant(0.3)(10**9) == 0.3


def test_masked_argmax_and_uniform_choice_respect_availability():
    q = torch.tensor([[5.0, 1.0, 9.0], [5.0, 1.0, 9.0]])
    avail = torch.tensor([[True, True, False], [False, True, False]])
    assert masked_argmax(q, avail).tolist() == [0, 1]
    u = torch.rand(1000, 4)
    picks = uniform_choice(torch.tensor([[False, True, False, True]]).expand(1000, 4), u)
    assert set(picks.tolist()) == {1, 3}
    assert 400 < int((picks == 1).sum()) < 600


def test_epsilon_greedy_frequencies_and_greedy_flag():
    n, a = 20_000, 4
    q = torch.tensor([[0.0, 3.0, 1.0, 2.0]]).expand(n, a)
    avail = torch.ones(n, a, dtype=torch.bool)
    u = BatchRNG([0], n, "t").uniform(uniforms_needed(a))
    choice, greedy = EpsilonGreedy(0.2).select(q, avail, u, 0)
    freq = torch.bincount(choice, minlength=a).float() / n
    # greedy 0.8 + 0.2/4 on the best, 0.05 elsewhere
    assert torch.allclose(freq, torch.tensor([0.05, 0.85, 0.05, 0.05]), atol=0.01)
    assert torch.equal(greedy, choice == 1)


def test_boltzmann_matches_softmax():
    n = 40_000
    q = torch.tensor([[0.0, 1.0, 2.0]]).expand(n, 3)
    avail = torch.tensor([[True, True, True]]).expand(n, 3)
    u = BatchRNG([1], n, "t").uniform(uniforms_needed(3))
    choice, _ = Boltzmann(1.0).select(q, avail, u, 0)
    freq = torch.bincount(choice, minlength=3).float() / n
    assert torch.allclose(freq, torch.softmax(q[0], 0), atol=0.01)


def test_greedy_breaks_exact_ties_randomly():
    n = 10_000
    q = torch.zeros(n, 3)
    avail = torch.ones(n, 3, dtype=torch.bool)
    u = BatchRNG([2], n, "t").uniform(uniforms_needed(3))
    choice, greedy = Greedy().select(q, avail, u, 0)
    assert greedy.all()
    assert all(3000 < int((choice == k).sum()) < 3700 for k in range(3))
