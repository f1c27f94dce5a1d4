"""Figure 4.3's claim on the small AGV, against exact dynamic programming.

HAR and HDR reach the hierarchically optimal gain (0.75: always serve M1), RAR, MAXQ-Q and
HH-learning the recursively optimal one (0.15: alternate M1 and M2). A learner is judged by the
exact global gain (``hrl_torch.analysis.policy_gain``) of its greedy policy, read from its
tables with ``greedy_table``, from each of the 18 machine-room start states of the env. A
policy's gain from a start is exact (tolerance 1e-6); we require the optimal gain from at least
14 of the 18 starts: from states the learned policy never visits once it is good (e.g. the
machine-room side of D2 for "always M1") its greedy choices rest on stale values and may loop.
Budgets are the registered configuration's (``agents.small_agv.DOMAIN``) cut short.
"""

import pytest
import torch

from agents.small_agv import DOMAIN
from envs import agv_small as agv
from hrl_torch import analysis as A
from hrl_torch.continuing import greedy_table
from hrl_torch.experiment import RunOptions, build_trainer

HO, RO = 0.75, 0.15
STARTS = agv.MACHINE_ROOM_LOCATIONS * agv.N_STATUS  # empty AGV anywhere in the machine room


@pytest.fixture(scope="module")
def solved():
    g = DOMAIN.algos["har"].make_graph()
    model = A.FiniteModel.from_tables(*agv.transition_tables(), agv.decode)
    ho, ro = A.hierarchically_optimal(g, model), A.recursively_optimal(g, model)
    assert ho.gain == pytest.approx(HO) and ro.root_gain == pytest.approx(RO)
    return g, model


def train(algo, seeds, steps):
    opts = RunOptions(seeds=seeds, progress=False, tensorboard=False, eval_episodes=0)
    trainer = build_trainer(DOMAIN, algo, opts)  # the configured schedules, cut short
    trainer.train(steps=steps)
    return trainer


def start_gains(trainer, solved, model=None) -> torch.Tensor:
    """``[P, 18]`` exact gain of every learner's greedy policy from every start."""
    g, base = solved
    model = model or base
    tables = [greedy_table(trainer.learner, base.observations, p) for p in range(trainer.P)]
    return torch.stack([A.policy_gain(g, model, t)[STARTS] for t in tables])


def assert_reaches(gains: torch.Tensor, target: float) -> None:
    hits = ((gains - target).abs() < 1e-6).sum(1)
    assert (hits >= 14).all(), (hits.tolist(), gains.unique().tolist())


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["har", "hdr"])
def test_hierarchically_optimal_learners_reach_the_hierarchically_optimal_gain(algo, solved):
    assert_reaches(start_gains(train(algo, [0, 1, 2], 30_000), solved), HO)


@pytest.mark.slow
@pytest.mark.parametrize("algo,steps", [("maxq-q", 30_000), ("rar", 60_000)])
def test_recursively_optimal_learners_reach_the_recursively_optimal_gain(algo, steps, solved):
    assert_reaches(start_gains(train(algo, [0, 1, 2], steps), solved), RO)


@pytest.mark.slow
def test_hh_learning_reaches_the_recursively_optimal_gain_in_most_seeds(solved):
    gains = start_gains(train("hh", list(range(5)), 50_000), solved)
    at_ro = (((gains - RO).abs() < 1e-6).sum(1) >= 14).sum()
    assert at_ro >= 3, gains.median(1).values  # others: "always M1" (0.05), reproduction.md
    assert (gains < HO - 0.1).all()  # never the hierarchically optimal policy


@pytest.mark.slow
def test_literal_har_without_an_optimistic_gain_settles_on_a_worse_policy(solved):
    # with empty initial sums the gain lags the greedy policy's gain and the root's values
    # drift; HAR then settles on "always M1 through the nearest door" (docs/reproduction.md)
    from hrl_torch.learners import GainEstimate

    opts = RunOptions(seeds=[0, 1, 2], progress=False, tensorboard=False, eval_episodes=0)
    trainer = build_trainer(DOMAIN, "har", opts)
    trainer.learner.gains = GainEstimate(3)  # (0, 0): empty sums
    trainer.train(steps=60_000)
    assert (start_gains(trainer, solved).median(1).values < HO - 0.5).all()


def test_greedy_throughput_is_the_exact_one(solved):
    # HDR learns the hierarchically optimal policy fast; the evaluator's greedy throughput is
    # then 10,000 x the exact weighted delivery rate from the eval env's start states
    g, model = solved
    trainer = train("hdr", [0], 20_000)
    trainer.eval_env = DOMAIN.make_env([DOMAIN.eval_seed], 4)
    throughput, rate = trainer.evaluate()
    eval_starts = DOMAIN.make_env([DOMAIN.eval_seed], 4).reset()["observation"]
    table = greedy_table(trainer.learner, model.observations, 0)
    weights = model.with_reward(agv.delivery_weight_table())
    exact = 10_000 * A.policy_gain(g, weights, table)[eval_starts].mean()
    exact_rate = A.policy_gain(g, model, table)[eval_starts].mean()
    assert float(throughput[0]) == pytest.approx(float(exact), rel=1e-5)
    assert float(rate[0]) == pytest.approx(float(exact_rate), abs=1e-5)
    assert float(exact_rate) == pytest.approx(HO, abs=1e-6)
