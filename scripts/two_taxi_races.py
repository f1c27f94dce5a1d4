"""Lost races on the two-taxi-earlier task: empty arrivals of hand-written rules and of learned
policies.

An *empty arrival* is an empty taxi moving onto a station where nobody waits (with the text's
``Get``, a lost race or a wasted trip). Counts per taxi and 1,000 steps over 2,000 steps after
a 200-step burn-in, for the rules (``agents.two_taxi_rules``; 5 seeds x 4 rows, arrival rate
10 over the grid) and for the frozen greedy policies of run folders (their evaluation env).

    python scripts/two_taxi_races.py [RUN_DIR ...]
"""

from __future__ import annotations

import argparse

import torch

import agents  # noqa: F401  (registers the domains)
from agents.two_taxi_rules import RULES, RULES_EXTRA, RulePolicy
from envs.two_taxi import EMPTY, NO_PASSENGER, STATION_AT, TwoTaxiEnv
from hrl_torch.runs.experiment import evaluate_run

STEPS, BURN_IN = 2_200, 200


def empty_arrivals(env: TwoTaxiEnv, step) -> tuple[float, float]:
    """(empty arrivals per taxi and 1,000 steps, deliveries per 5,000 steps), ``step(k) -> td``."""
    arrivals = deliveries = 0.0
    none = torch.full((env.batch_size, 1), NO_PASSENGER)
    for k in range(STEPS):
        before = env.taxi_loc.clone()
        td = step(k)
        station = STATION_AT[env.taxi_loc]  # N_STATIONS off the stations
        nobody = torch.cat([env.station_dest, none], 1).gather(1, station) == NO_PASSENGER
        event = (env.taxi_loc != before) & (station < 4) & nobody & (env.status == EMPTY)
        if k >= BURN_IN:
            arrivals += float(event.sum())
            deliveries += float(td["n_delivered"].sum())
    window = (STEPS - BURN_IN) * env.batch_size
    return arrivals / (window * env.n_agents) * 1_000, deliveries / window * 5_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="*", help="run folders of a two-taxi-earlier domain")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print("| policy | empty arrivals per taxi and 1,000 steps | deliveries per 5,000 steps |")
    print("|---|---:|---:|")
    for rule in RULES + RULES_EXTRA:
        env = TwoTaxiEnv([0, 1, 2, 3, 4], 4)
        policy = RulePolicy(env, rule)
        env.reset()
        a, d = empty_arrivals(env, lambda k, env=env, policy=policy: env.step(policy.act()))
        print(f"| rule {rule} | {a:.1f} | {d:.1f} |", flush=True)
    for run_dir in args.runs:
        trainer, _ = evaluate_run(run_dir)
        env = trainer.eval_env
        env.rng.load_state_dict({"counter": 0})
        agent = trainer.evaluation_agent(env, "eval-explore")
        agent.freeze_values(STEPS)
        action = [agent.start(env.reset())]

        def step(k, env=env, agent=agent, action=action):
            td = env.step(action[0])
            action[0] = agent.step(td)
            return td

        a, d = empty_arrivals(env, step)
        print(f"| {trainer.run_config['algo']} ({run_dir}) | {a:.1f} | {d:.1f} |", flush=True)


if __name__ == "__main__":
    main()
