"""Trace Cooperative HRL on trash (issue 22): train one variant, print its exact gains.

Every variant starts from the setup of ``scripts/trash_exact.py`` with the completions of every
subtask starting at -10 (the setup before issue 22) and changes one thing or a few: the broadcast
rule, the root's initial completions, the step size, exploration, all-states updating, the
termination scheme, a team utility at the root, a second cooperation level. The rows of the
trace table in ``docs/reproduction.md`` ("Trash collection") came from it::

    python scripts/trash_trace.py --broadcast simultaneous            # as before issue 22
    python scripts/trash_trace.py --root-init 0                       # the new default
    python scripts/trash_trace.py --root-init 0 --alpha lin:0.2:0.02 --steps 300000
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch

from agents import trash as T
from envs.trash import DUMP_REWARD
from hrl_torch import registry
from hrl_torch.executor import ExecutorConfig
from hrl_torch.experiment import RunOptions, build_trainer
from hrl_torch.exploration import EpsilonGreedy, Linear
from hrl_torch.graph import Subtask, TaskGraph
from hrl_torch.learners import MaxQLearner
from hrl_torch.multiagent import Cooperation
from scripts.trash_exact import exact_gains


def _arguments() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algo", default="cooperative", choices=("cooperative", "selfish"))
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--steps", type=int, default=150_000)
    p.add_argument("--alpha", default="0.2", help="a number, or lin:START:END over the run")
    p.add_argument("--eps-frac", type=float, default=0.5, help="epsilon decays over this share")
    p.add_argument("--broadcast", default="sequential", choices=("sequential", "simultaneous"))
    p.add_argument("--scheme", default="continue", choices=("continue", "any", "all"))
    p.add_argument("--root-init", type=float, default=None, help="the root's initial C")
    p.add_argument("--visited", type=int, default=0, help="all-states updating, visits kept")
    p.add_argument("--team-root", action="store_true", help="others' dumps: root's internal r")
    p.add_argument("--two-levels", action="store_true", help="Collect subtasks cooperative too")
    p.add_argument("--shared-tables", action="store_true", help="both robots learn one table")
    return p.parse_args()


def _team_hierarchy() -> TaskGraph:
    """Figure 6.1 with the other robots' dumps (+20 each) as the root's internal reward."""
    root = Subtask(
        "Root",
        T.U1,
        n_states=T.ROOT_STATES,
        abstract=T._root_state,
        shaping_reward=lambda o, a, o2: DUMP_REWARD * (o2["n_dumped"] - o2["dumped"]).float(),
    )
    return TaskGraph("Root", [root, *T._collection_nodes()], n_actions=T.N_ACTIONS)


def _variant(a: argparse.Namespace):
    """The trash domain with ``a.algo`` changed as asked, and its multi-agent config."""
    dom = registry.get("trash")
    alpha = float(a.alpha) if not a.alpha.startswith("lin") else None
    if alpha is None:
        _, start, end = a.alpha.split(":")
        alpha = Linear(float(start), float(end), a.steps)
    init_nodes = None if a.root_init is None else {"Root": a.root_init}

    def learner(graph, sets):
        return MaxQLearner(
            graph, sets, alpha, T.GAMMA, all_states=bool(a.visited), init=T.INIT,
            init_nodes=init_nodes,
        )  # fmt: skip

    levels = (("Root",), ("CollectT1", "CollectT2")) if a.two_levels else (("Root",),)
    cooperation = Cooperation(levels, wait="Wait", broadcast=a.broadcast)
    base = _team_hierarchy if a.team_root else T.trash_hierarchy
    spec = replace(
        dom.algos[a.algo],
        learner=learner,
        exploration=lambda c: EpsilonGreedy(Linear(0.5, 0.02, int(c.steps * a.eps_frac))),
        executor=ExecutorConfig(record_visited=a.visited),
    )
    if a.algo == "cooperative":
        config = replace(
            spec.multiagent, cooperation=cooperation, scheme=a.scheme, shared_tables=a.shared_tables
        )
        spec = replace(
            spec, make_graph=lambda: T.cooperative_graph(base(), cooperation, 2), multiagent=config
        )
    return replace(dom, algos={**dom.algos, a.algo: spec}), spec.multiagent


def main() -> None:
    a = _arguments()
    torch.set_num_threads(1)
    domain, config = _variant(a)
    start = time.perf_counter()
    opts = RunOptions(seeds=list(range(a.seeds)), steps=a.steps, progress=False, tensorboard=False)
    trainer = build_trainer(domain, a.algo, opts)
    trainer.config.eval_every = 0
    trainer.train()
    gains = exact_gains(trainer, a.algo, 2, T.REFILL_PROB, config)
    mean = sum(gains) / len(gains)
    took = time.perf_counter() - start
    print(f"{[round(g, 3) for g in gains]} mean {mean:.3f} ({took:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
