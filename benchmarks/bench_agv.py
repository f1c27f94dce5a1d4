"""AGV scheduling (Chapter 4): training speed of the population runs and the flat table's memory.

For each (domain, algorithm) it builds the registered configuration with ``P`` seeds and ``E``
envs per seed, trains a few hundred batched steps to warm up, then times ``--seconds`` of
training (no evaluation) and reports env steps per second of the whole population. Memory:
the process's peak resident set (``ru_maxrss``) after each configuration, and the bytes of the
learner's tables. Run each configuration in a fresh process (``--one``) for a clean peak.

    PYTHONPATH=. .venv/bin/python -m benchmarks.bench_agv [--seconds 20] [--envs 64]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import torch


def measure(domain: str, algo: str, seeds: int, envs: int, seconds: float) -> dict:
    import agents  # noqa: F401
    from hrl_torch.modules.tables import TableBank
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    torch.set_num_threads(1)
    opts = RunOptions(
        seeds=list(range(seeds)),
        envs_per_learner=envs,
        eval_episodes=0,
        progress=False,
        tensorboard=False,
    )
    trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(200):  # warm-up (and out of the fully random first steps)
        trainer.train_step()
    start_step, t0, c0 = trainer.step, time.perf_counter(), time.process_time()
    while time.perf_counter() - t0 < seconds:
        trainer.train_step()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    steps = (trainer.step - start_step) * seeds
    table_bytes = sum(
        b.store.numel() * b.store.element_size()
        for b in trainer.learner.modules()
        if isinstance(b, TableBank)
    )
    return {
        "domain": domain,
        "algo": algo,
        "seeds": seeds,
        "envs_per_seed": envs,
        "env_steps": steps,
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "env_steps_per_s": round(steps / wall),
        "ms_per_batched_step": round(1000 * wall / (trainer.step - start_step) * envs, 2),
        "table_mb": round(table_bytes / 2**20, 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--envs", type=int, nargs="+", default=[64])
    parser.add_argument("--domains", nargs="+", default=["agv", "agv-ct"])
    parser.add_argument("--algos", nargs="+", default=["har", "rar", "hdr", "rvi-q"])
    parser.add_argument(
        "--one", nargs=3, metavar=("DOMAIN", "ALGO", "ENVS"), help=argparse.SUPPRESS
    )
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    if args.one:
        domain, algo, envs = args.one
        print(json.dumps(measure(domain, algo, args.seeds, int(envs), args.seconds)))
        return
    print(f"load average at start: {os.getloadavg()}", flush=True)
    rows = []
    for domain in args.domains:
        for algo in args.algos:
            for envs in args.envs:
                cmd = [
                    sys.executable,
                    "-m",
                    "benchmarks.bench_agv",
                    "--one",
                    domain,
                    algo,
                    str(envs),
                    "--seconds",
                    str(args.seconds),
                    "--seeds",
                    str(args.seeds),
                ]
                out = subprocess.run(cmd, capture_output=True, text=True, check=True)
                row = json.loads(out.stdout.strip().splitlines()[-1])
                rows.append(row)
                print(row, flush=True)
    print(f"load average at end: {os.getloadavg()}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
