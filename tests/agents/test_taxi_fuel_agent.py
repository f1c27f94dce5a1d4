"""The taxi-fuel-earlier hierarchy (Dietterich 1998 with Refuel) and its learners."""

import pytest
import torch

from agents.taxi_fuel import DOMAIN, FUEL_LOC, taxi_fuel_hierarchy
from envs.taxi_fuel import CAPACITY, TaxiFuelEnv
from hrl_torch.runs.experiment import RunOptions, build_trainer


def test_refuel_is_available_below_a_full_tank_and_ends_with_fillup():
    g = taxi_fuel_hierarchy()
    env = TaxiFuelEnv(list(range(4)), 64)
    obs = env.reset()
    ctx = g.context(obs)
    root, refuel = g.index["Root"], g.index["Refuel"]
    full = obs["fuel"] == CAPACITY
    assert torch.equal(ctx.available[:, root, 2], ~full)
    assert torch.equal(ctx.terminated[:, refuel], full)
    nav_f = g.node("Navigate_F")
    assert int(nav_f.target_loc) == FUEL_LOC == 17
    assert g.node("Root").n_states == 260


def _trainer(algo, steps, seeds=3, eval_every=None, envs_per_learner=None):
    opts = RunOptions(
        seeds=list(range(seeds)),
        steps=steps,
        eval_every=steps // 4 if eval_every is None else eval_every,
        envs_per_learner=envs_per_learner,
        progress=False,
        tensorboard=False,
    )
    return build_trainer(DOMAIN, algo, opts)


def _train(algo, steps, seeds=3, eval_every=None):
    return _trainer(algo, steps, seeds, eval_every).train()


def test_hpgrl_improves_the_greedy_return():
    # baseline, measured here: the untrained policy (every parameter 0; evaluated on its
    # modes it takes the first available child everywhere) returns -28.69 on the eval
    # episodes and never delivers (it runs dry after 9.7 steps on average). After 160,000
    # env steps per seed (1,024 envs per seed), 10 seeds returned -1.3 to -9.2 (median -5.5)
    # and delivered in 85-93% of the episodes; 2 of the 10 returned about -26, their greedy
    # policy looping in a few episodes until the 200-step cap (the code before the core
    # rewrite gave the same spread: median -5.0, 2 of 10 near -30). So: every seed delivers,
    # and at least two of the three seeds gain more than 15 over the untrained policy (seeds
    # 0-2 return -9.2, -26.5, -5.4). MAXQ-Q's best mean in Figure 5.3 is -4.8;
    # test_hpgrl_reaches_maxq_q_level (slow) checks that level
    trainer = _trainer("hpgrl", 160_000, eval_every=0, envs_per_learner=1024)
    untrained, untrained_success = trainer.evaluate()
    assert torch.allclose(untrained, torch.tensor(-28.69), atol=0.01)
    assert (untrained_success == 0).all()
    result = trainer.train()
    final = torch.tensor(result.final_eval)
    assert int((final > untrained + 15).sum()) >= 2, (untrained, result.final_eval)
    assert (torch.tensor(result.final_success) > 0.75).all(), result.final_success


def test_running_dry_is_not_a_success():
    from hrl_torch.training.evaluation import succeeded as _succeeded

    td = {
        "terminated": torch.tensor([True, True, False]),
        "out_of_fuel": torch.tensor([False, True, False]),
    }
    assert _succeeded(td, "!out_of_fuel").tolist() == [True, False, False]
    assert DOMAIN.algos["hpgrl"].train.success_key == "!out_of_fuel"


@pytest.mark.slow
def test_maxq_q_reaches_minus_10_before_flat_q():
    # Figure 5.3's ordering on our runs (10 seeds): MAXQ-Q median 358k env steps, flat Q 758k
    def first_hit(result, threshold=-10.0):
        hits = []
        for p in range(len(result.final_eval)):
            hit = [s for s, values in result.curve if values[p] >= threshold]
            hits.append(hit[0] if hit else float("inf"))
        return sorted(hits)[len(hits) // 2]

    maxq = _train("maxq-q", 700_000, seeds=5, eval_every=50_000)
    flat = _train("q", 1_200_000, seeds=5, eval_every=50_000)
    assert first_hit(maxq) < first_hit(flat) < float("inf")


@pytest.mark.slow
def test_hpgrl_reaches_maxq_q_level():
    # 3 seeds at 600k env steps ended at -0.1, 0.2, 0.2 (MAXQ-Q's best mean in Figure 5.3: -4.8)
    result = _train("hpgrl", 600_000, eval_every=100_000)
    assert min(result.final_eval) >= -10.0, result.curve
