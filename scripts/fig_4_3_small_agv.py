"""Figure 4.3: HAR and HDR find the hierarchically optimal policy on the small AGV, RAR,
MAXQ-Q and HH-learning only the recursively optimal one.

Runs the five curves (10 seeds each, as in the text) through the CLI, plots greedy and
training throughput (``20 x part 1 + part 2`` per 10,000 steps), and classifies every learned
greedy policy by its exact gain (``hrl_torch.analysis``): hierarchically optimal (0.75,
throughput 16,667), recursively optimal (0.15, 10,500) or other. Writes ``runs/fig_4_3/``.

    python scripts/fig_4_3_small_agv.py [--seeds 10] [--steps 150000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from chapter4 import plots, run_cli, table, write

from agents.small_agv import DOMAIN
from envs import agv_small as agv
from hrl_torch import analysis as A
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.continuing import greedy_table

ALGOS = {"HAR": "har", "HDR": "hdr", "RAR": "rar", "MAXQ-Q": "maxq-q", "HH-learning": "hh"}
HO, RO = 0.75, 0.15


def classify(run: Path, algo: str, seeds: int, steps: int | None) -> dict[str, int]:
    """Exact gain of each seed's final greedy policy (median over the machine-room starts)."""
    opts = RunOptions(seeds=list(range(seeds)), steps=steps, progress=False, tensorboard=False)
    trainer = build_trainer(DOMAIN, algo, opts)
    trainer.load(run / "checkpoint.pt")
    graph = trainer.graph
    model = A.FiniteModel.from_tables(*agv.transition_tables(), agv.decode)
    starts = agv.MACHINE_ROOM_LOCATIONS * agv.N_STATUS
    counts = {"hierarchically optimal": 0, "recursively optimal": 0, "other": 0}
    gains = []
    for p in range(seeds):
        table_p = greedy_table(trainer.learner, model.observations, p)
        gain = float(torch.median(A.policy_gain(graph, model, table_p)[starts]))
        gains.append(round(gain, 3))
        key = (
            "hierarchically optimal"
            if abs(gain - HO) < 1e-6
            else "recursively optimal"
            if abs(gain - RO) < 1e-6
            else "other"
        )
        counts[key] += 1
    return {**counts, "gains": gains}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=None, help="env steps per seed")
    parser.add_argument("--out", default="runs")
    args = parser.parse_args()
    root = Path(args.out)
    out = root / "fig_4_3"
    runs = {
        label: run_cli("small-agv", algo, args.seeds, root, args.steps)
        for label, algo in ALGOS.items()
    }
    plots(runs, out, "Figure 4.3, small AGV", DOMAIN.reference)
    rows = [
        "| algorithm | hierarchically optimal | recursively optimal | other | exact gains |",
        "|---|---|---|---|---|",
    ]
    for label, run in runs.items():
        c = classify(run, ALGOS[label], args.seeds, args.steps)
        rows.append(
            f"| {label} | {c['hierarchically optimal']} | {c['recursively optimal']} | "
            f"{c['other']} | {c['gains']} |"
        )
    text = "\n\n".join(
        [table(runs), "\n".join(rows), "\n".join(f"- {k}: `{v}`" for k, v in runs.items())]
    )
    write(out, "table.md", text)


if __name__ == "__main__":
    main()
