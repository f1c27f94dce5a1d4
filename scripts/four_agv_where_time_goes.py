"""Where the time goes in a four-AGV run: what the AGVs and the machines do under its policy.

Re-runs a finished run folder's policies greedily (the run's own evaluation: the same eval env,
arrivals and window) and, over the counted window, splits the time of every AGV into moving,
loading / unloading, waiting at an empty bay, at a full ``Di``, at an empty ``Pi``, and other
idling, and the time of every machine into busy, starved (``Di`` empty) and blocked (``Pi``
full). Prints the shares (mean over seeds) and the throughput. It explains what caps a policy:
machines busy all the time mean the capacity (166.7 assemblies per 1,000 s); AGVs waiting most
of the time mean the vehicles.

    python scripts/four_agv_where_time_goes.py RUN_DIR [RUN_DIR ...] [--window SECONDS]
"""

from __future__ import annotations

import argparse

import torch

import agents  # noqa: F401  (registers the domains)
from envs.four_agv import BAYS, DROP_OFF, IDLE, N_MOVES, PICK_UP
from hrl_torch.runs.experiment import evaluate_run

AGV_KINDS = ("moving", "load/unload", "wait bay", "wait full D", "wait empty P", "other idle")
MACHINE_KINDS = ("busy", "starved", "blocked")


def _agv_kind(env, running: torch.Tensor) -> torch.Tensor:
    """``[B, n]`` index into ``AGV_KINDS`` of what every AGV is doing now."""
    loc, status = env.location, env.status
    dev = loc.device
    at = {name: torch.tensor(v, device=dev) for name, v in (("W", BAYS), ("D", DROP_OFF))}
    at["P"] = torch.tensor(PICK_UP, device=dev)
    empty = status == 0
    bay = (loc[..., None] == at["W"]).long().argmax(-1)
    at_bay = (loc[..., None] == at["W"]).any(-1)
    no_part = env.warehouse.gather(1, bay) == 0
    at_d = (loc[..., None] == at["D"]).any(-1)
    station = (loc[..., None] == at["D"]).long().argmax(-1)
    full = env.drop_off.gather(1, station) >= env.capacity
    at_p = (loc[..., None] == at["P"]).any(-1)
    idle = running == IDLE
    kind = torch.full_like(loc, 5)
    kind = torch.where(idle & empty & at_p, 4, kind)
    kind = torch.where(idle & ~empty & at_d & full, 3, kind)
    kind = torch.where(idle & empty & at_bay & no_part, 2, kind)
    kind = torch.where(~idle & (running >= N_MOVES), 1, kind)
    return torch.where(running < N_MOVES, 0, kind)


def _machine_kind(env) -> torch.Tensor:
    """``[B, 4]`` index into ``MACHINE_KINDS``."""
    blocked = ~env.busy & (env.drop_off > 0)
    return torch.where(env.busy, 0, torch.where(blocked, 2, 1))


def where_time_goes(run_dir: str, window: float | None = None) -> str:
    """Shares of AGV and machine time over the run's greedy evaluation window.

    ``window``: count this many seconds after the burn-in instead of the run's window.
    """
    trainer, _ = evaluate_run(run_dir)
    return f"{run_dir}: " + trainer_time_shares(trainer, window)


def trainer_time_shares(trainer, window: float | None = None) -> str:
    """``where_time_goes`` for a trainer's (trained) greedy policies, without a run folder."""
    ev, env = trainer.evaluator, trainer.eval_env
    if window is not None:
        ev.horizon_time = window
    env.rng.load_state_dict({"counter": 0})
    agent = trainer.evaluation_agent(env, "eval-explore")
    agent.freeze_values(ev.max_steps)
    action = agent.start(env.reset())
    running = torch.full_like(env.location, IDLE)
    agv_time = torch.zeros(len(AGV_KINDS), dtype=torch.float64)
    machine_time = torch.zeros(len(MACHINE_KINDS), dtype=torch.float64)
    station_busy = torch.zeros(env.drop_off.shape[1], dtype=torch.float64)
    clock = torch.zeros(env.batch_size, dtype=torch.float64)
    delivered, counted = 0.0, 0.0
    end = ev.burn_in_time + ev.horizon_time
    for _ in range(ev.max_steps):
        running = torch.where(env.acting, action.long(), running)
        agv, machine = _agv_kind(env, running), _machine_kind(env)
        td = env.step(action)
        dt = td["duration"].double()
        count = ((clock >= ev.burn_in_time) & (clock < end)).double() * dt
        agv_time += torch.zeros_like(agv_time).index_add_(
            0, agv.flatten(), count[:, None].expand_as(agv).flatten()
        )
        machine_time += torch.zeros_like(machine_time).index_add_(
            0, machine.flatten(), count[:, None].expand_as(machine).flatten()
        )
        station_busy += ((machine == 0).double() * count[:, None]).sum(0)
        delivered += float((td["assemblies_delivered"].double() * (count > 0)).sum())
        counted += float(count.sum())
        clock += dt
        if bool((clock >= end).all()):
            break
        action = agent.step(td)
    agv_share = agv_time / agv_time.sum()
    machine_share = machine_time / machine_time.sum()
    lines = [f"{delivered / counted * 1000:.1f} assemblies per 1,000 s greedy"]
    lines.append(
        "  AGV time: "
        + ", ".join(f"{k} {v:.1%}" for k, v in zip(AGV_KINDS, agv_share, strict=True))
    )
    lines.append(
        "  machine time: "
        + ", ".join(f"{k} {v:.1%}" for k, v in zip(MACHINE_KINDS, machine_share, strict=True))
    )
    busy = station_busy / counted
    lines.append(
        "  busy per machine: " + ", ".join(f"M{k + 1} {v:.1%}" for k, v in enumerate(busy))
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dirs", nargs="+")
    parser.add_argument("--window", type=float, help="seconds counted (default: the run's)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for run_dir in args.run_dirs:
        print(where_time_goes(run_dir, args.window), flush=True)


if __name__ == "__main__":
    main()
