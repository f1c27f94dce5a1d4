"""The training loop's clocks: steps, training and evaluation seconds, real env steps, next due."""

from __future__ import annotations

import torch


class LoopCounters:
    """The loop's clock and counters: what a checkpoint keeps of the loop itself.

    ``step`` is the agent's clock (env steps per learner); ``train_seconds`` the time spent
    stepping; ``eval_seconds`` the time spent in greedy evaluations; ``real_steps [P]`` the
    env steps each learner really took (rows being auto-reset take none); ``next`` the steps
    at which logging, evaluation and checkpointing are due.
    """

    def __init__(self, agent, n_learners: int, eval_every: int, device) -> None:
        self.agent = agent
        self.train_seconds = 0.0
        self.eval_seconds = 0.0
        self.real_steps = torch.zeros(n_learners, dtype=torch.float64, device=device)
        self.next = {"log": 0, "eval": eval_every, "ckpt": 0}

    def state_dict(self) -> dict:
        """The counters, in a checkpoint's keys."""
        return {
            "step": self.agent.clock,
            "train_seconds": self.train_seconds,
            "eval_seconds": self.eval_seconds,
            "real_steps": self.real_steps.clone(),
            "next": dict(self.next),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``."""
        self.agent.clock = int(state["step"])
        self.train_seconds = float(state["train_seconds"])
        self.eval_seconds = float(state.get("eval_seconds", 0.0))  # (older checkpoints: none)
        self.real_steps = state["real_steps"].clone()
        self.next = {k: int(v) for k, v in state["next"].items()}
