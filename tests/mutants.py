"""Curated one-line mutations of the core for ``scripts/mutate.py`` (``make mutate``).

Each mutant replaces one exact snippet (it must occur once in its file) with a plausible bug:
a wrong sign, a missing discount exponent, a state read at the wrong time, a field not restored
from a checkpoint. The first seventeen are the bugs of the issue that asked for this check;
the rest cover the executor, graph, tables, exploration, tiles, env base, checkpoints and the
domain envs. ``first`` names the test files most likely to catch the mutant (run first, so a
kill is quick); the verdict is always the fast suite's.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Mutant:
    """One single-snippet mutation."""

    name: str
    file: str
    find: str
    replace: str
    why: str
    first: tuple[str, ...] = ()


MULTISTEP = "tests/learners/test_hand_computed_targets.py"
SMALL_EXACT = "tests/learners/test_q_lambda_and_hh_exact.py"
MAXQ_EXACT = "tests/learners/test_maxq_exact.py"
AVERAGE = "tests/learners/test_average_reward.py"
RESUME = "tests/test_resume_every_algorithm.py"
PG = (
    "tests/test_policies.py",
    "tests/learners/test_pg_scores.py",
    "tests/learners/test_hpgrl.py",
)
EXECUTOR = "tests/test_executor.py"
TABLES = "tests/test_tables.py"

MUTANTS: list[Mutant] = [
    # ---------------------------------------------------------------- the seventeen
    Mutant(
        "maxq-td-sign",
        "hrl_torch/learners/maxq.py",
        "external = torch.where(terminal, 0.0, discount * v_next)",
        "external = torch.where(terminal, 0.0, -discount * v_next)",
        "MAXQ external completion target with its sign flipped",
        (MULTISTEP, MAXQ_EXACT),
    ),
    Mutant(
        "maxq-no-discount",
        "hrl_torch/learners/maxq.py",
        'discount(self.gamma, level["duration"]),',
        'torch.ones_like(level["duration"]),',
        "MAXQ completion targets not discounted",
        (MULTISTEP, MAXQ_EXACT),
    ),
    Mutant(
        "maxq-gamma-not-gamma-n",
        "hrl_torch/learners/maxq.py",
        'discount(self.gamma, level["duration"]),',
        'discount(self.gamma, torch.ones_like(level["duration"])),',
        "MAXQ discounts a multi-step child by gamma instead of gamma^N",
        (MULTISTEP, MAXQ_EXACT),
    ),
    Mutant(
        "maxq-external-learns-internal",
        "hrl_torch/learners/maxq.py",
        "self.C.update(idx.reshape(-1), target.reshape(-1), alpha, valid.reshape(-1))",
        "self.C.update(idx.reshape(-1), target_int.reshape(-1), alpha, valid.reshape(-1))",
        "MAXQ's external completion learns the internal (pseudo-reward) target",
        (MULTISTEP,),
    ),
    Mutant(
        "smdp-continuation-sign",
        "hrl_torch/learners/q_learning.py",
        '+ level["internal_reward"] + factor * continuation',
        '+ level["internal_reward"] - factor * continuation',
        "SMDP-Q continuation with its sign flipped",
        (MULTISTEP,),
    ),
    Mutant(
        "smdp-gamma-not-gamma-tau",
        "hrl_torch/learners/q_learning.py",
        'factor = discount(self.gamma, level["duration"])',
        'factor = discount(self.gamma, torch.ones_like(level["duration"]))',
        "SMDP-Q discounts a multi-step option by gamma instead of gamma^tau",
        (MULTISTEP,),
    ),
    Mutant(
        "executor-no-abort",
        "hrl_torch/executor.py",
        "popped = (cut.cumsum(1) > 0) & active",
        "popped = cut & active",
        "a terminating subtask does not abort the subtasks it called",
        (EXECUTOR,),
    ),
    Mutant(
        "executor-reward-not-restored",
        "hrl_torch/stack.py",
        "setattr(self, k, v.to(mine[k].device).clone())",
        'setattr(self, k, v.to(mine[k].device).clone()) if k != "reward" else None',
        "the executor's accumulated reward is not restored from a checkpoint",
        (RESUME,),
    ),
    Mutant(
        "tiles-offset-sign",
        "hrl_torch/tiles.py",
        "shifted = scaled.unsqueeze(-2) + offsets",
        "shifted = scaled.unsqueeze(-2) - offsets",
        "tilings displaced the wrong way",
        ("tests/test_tiles.py",),
    ),
    Mutant(
        "har-gain-without-time",
        "hrl_torch/learners/average_reward.py",
        'return prim["reward"] - self.gain[batch["learner"]] * self.primitive_time(batch)',
        'return prim["reward"] - self.gain[batch["learner"]]',
        "HAR charges the gain per step, not per unit of time (continuous time)",
        (MULTISTEP, AVERAGE),
    ),
    Mutant(
        "taxi-moves-swapped",
        "envs/taxi.py",
        "SOUTH, NORTH, EAST, WEST, PICKUP, DROPOFF = range(6)",
        "NORTH, SOUTH, EAST, WEST, PICKUP, DROPOFF = range(6)",
        "taxi's north and south swapped",
        ("tests/envs/test_taxi.py",),
    ),
    Mutant(
        "env-elapsed-not-restored",
        "hrl_torch/env.py",
        'for k in (*self.state_keys, "elapsed", "done"):',
        'for k in (*self.state_keys, "done"):',
        "an env's episode clock is not restored from a checkpoint",
        (RESUME,),
    ),
    Mutant(
        "softmax-score-without-pi",
        "hrl_torch/policies.py",
        "score = torch.where(ok, softmax_score(probs, pick), 0.0)",
        "score = torch.where(ok, torch.nn.functional.one_hot(pick, probs.shape[-1]).float(), 0.0)",
        "softmax likelihood ratio without its -pi term",
        PG,
    ),
    Mutant(
        "rar-update-at-next-state",
        "hrl_torch/learners/average_reward.py",
        'idx = self.C.index(learner, table, level["state"], level["child"])',
        'idx = self.C.index(learner, table, level["next_state"], level["child"])',
        "RAR updates C at s' instead of s",
        (MULTISTEP, AVERAGE),
    ),
    Mutant(
        "hdr-gamma-not-gamma-t",
        "hrl_torch/learners/hdr.py",
        "return discount(self.gamma, t)",
        "return discount(self.gamma, torch.ones_like(t))",
        "HDR discounts by gamma instead of gamma^t",
        (MULTISTEP,),
    ),
    Mutant(
        "rar-bootstrap-from-child",
        "hrl_torch/learners/average_reward.py",
        'h_next = ctx.values["H"].gather(1, table)',
        'h_next = ctx.values["H"].gather(1, child_table)',
        "RAR bootstraps from the child's value instead of the subtask's at s'",
        (MULTISTEP, AVERAGE),
    ),
    Mutant(
        "gaussian-score-sign",
        "hrl_torch/policies.py",
        "per_tile = (u - mean) / (sigma**2 * n_tiles)",
        "per_tile = (mean - u) / (sigma**2 * n_tiles)",
        "HPGRL's Gaussian score with its sign flipped",
        PG,
    ),
    Mutant(
        "gaussian-score-squashed",
        "hrl_torch/policies.py",
        "score = gaussian_tile_score(pre, mean, tiles.shape[-1], self.sigma)",
        "score = gaussian_tile_score(squash(pre, self.low, self.high), mean, tiles.shape[-1], "
        "self.sigma)",
        "HPGRL's Gaussian score computed on the squashed action",
        PG,
    ),
    # ---------------------------------------------------------------- learners
    Mutant(
        "maxq-external-picks-internal-value",
        "hrl_torch/learners/maxq.py",
        "external = (child_v + c).gather(-1, best)[..., 0]",
        "external = (child_v + c_int).gather(-1, best)[..., 0]",
        "MAXQ's V(i, s) reads the internal completion",
        (MULTISTEP,),
    ),
    Mutant(
        "maxq-primitive-learns-nothing",
        "hrl_torch/learners/maxq.py",
        'self.V.update(pidx, prim["reward"], alpha, prim["valid"])\n',
        'self.V.update(pidx, prim["reward"], alpha, ~prim["valid"])\n',
        "MAXQ updates the primitive values of the wrong rows",
        (MAXQ_EXACT,),
    ),
    Mutant(
        "maxq-pseudo-undiscounted",
        "hrl_torch/learners/maxq.py",
        "internal = internal + discount * torch.where(terminal, pseudo, v_next_int)",
        "internal = internal + torch.where(terminal, pseudo, discount * v_next_int)",
        "MAXQ's pseudo reward at s' is not discounted by gamma^N",
        (MULTISTEP,),
    ),
    Mutant(
        "three-part-ce-terminal-swapped",
        "hrl_torch/learners/three_part.py",
        "external = discount * torch.where(terminal, outer_next, ce_next)",
        "external = discount * torch.where(terminal, ce_next, outer_next)",
        "CE continues with its own value at a terminal state and the parent's elsewhere",
        (SMALL_EXACT, MULTISTEP, AVERAGE),
    ),
    Mutant(
        "three-part-choice-without-ce",
        "hrl_torch/learners/three_part.py",
        "return child_v + self.C.read(idx, ok) + self.CE.read(idx, ok)",
        "return child_v + self.C.read(idx, ok)",
        "three-part learners choose without the external completion (recursive optimality)",
        (
            SMALL_EXACT,
            AVERAGE,
        ),
    ),
    Mutant(
        "three-part-w-not-handed-over",
        "hrl_torch/learners/three_part.py",
        "outer[:, ids] = torch.where(ended, outer[:, self._parent[ids]], full[:, ids])",
        "outer[:, ids] = full[:, ids]",
        "W of an instance that ended does not hand over to its parent",
        (SMALL_EXACT, MULTISTEP, AVERAGE),
    ),
    Mutant(
        "har-gain-from-exploratory-steps",
        "hrl_torch/learners/average_reward.py",
        'seen = prim["valid"] & prim["greedy"]  # M_i and its ancestors non-random',
        'seen = prim["valid"]',
        "HAR's gain also counts exploratory steps (Algorithm 1 line 6)",
        (MULTISTEP, AVERAGE),
    ),
    Mutant(
        "rar-gain-sign",
        "hrl_torch/learners/average_reward.py",
        "target = h_next - (g_i - g_a) * t",
        "target = h_next - (g_i + g_a) * t",
        "RAR charges the child's gain with the wrong sign",
        (MULTISTEP, AVERAGE),
    ),
    Mutant(
        "hh-model-records-start-state",
        "hrl_torch/learners/hh_learning.py",
        'outcome = torch.where(terminal, n_out - 1, level["next_state"])',
        'outcome = torch.where(terminal, n_out - 1, level["state"])',
        "HH-learning's model records s instead of s'",
        (
            SMALL_EXACT,
            AVERAGE,
        ),
    ),
    Mutant(
        "hh-gain-sign",
        "hrl_torch/learners/hh_learning.py",
        "h = r - self.gain[ctx.learner][:, None] * tau",
        "h = r + self.gain[ctx.learner][:, None] * tau",
        "HH-learning adds the gain instead of subtracting it",
        (
            SMALL_EXACT,
            AVERAGE,
        ),
    ),
    Mutant(
        "rvi-reference-sign",
        "hrl_torch/learners/rvi_q.py",
        'target = level["reward"][:, 0] - self.reference()[learner] * t + v_next',
        'target = level["reward"][:, 0] + self.reference()[learner] * t + v_next',
        "RVI Q-learning adds f(Q) instead of subtracting it",
        (AVERAGE,),
    ),
    Mutant(
        "rvi-sum-counts-duplicates",
        "hrl_torch/learners/rvi_q.py",
        "self.q_sum.index_add_(0, learner, (change / counts[inverse]).double())",
        "self.q_sum.index_add_(0, learner, change.double())",
        "RVI-Q's running table sum counts an entry hit by several rows several times",
        (AVERAGE,),
    ),
    Mutant(
        "pg-reward-to-go-forward",
        "hrl_torch/learners/pg.py",
        "weight = reward.flip(1).cumsum(1).flip(1)",
        "weight = reward.cumsum(1)",
        "HPGRL weighs each score by the reward before it, not the reward-to-go (Eq. 5.2)",
        PG,
    ),
    Mutant(
        "q-lambda-no-discount",
        "hrl_torch/learners/q_lambda.py",
        'discount = self.gamma ** pick("duration")',
        'discount = self.gamma ** torch.ones_like(pick("duration"))',
        "Q(lambda) discounts a multi-step child by gamma instead of gamma^tau",
        (
            SMALL_EXACT,
            "tests/learners/test_q_lambda.py",
        ),
    ),
    Mutant(
        "q-lambda-traces-not-cut",
        "hrl_torch/learners/q_lambda.py",
        'trace = torch.where(take(pick("greedy"))[:, None], trace, 0.0)',
        "trace = trace",
        "Watkins' Q(lambda) keeps traces across exploratory choices",
        (
            SMALL_EXACT,
            "tests/learners/test_q_lambda.py",
        ),
    ),
    # ---------------------------------------------------------------- tables and exploration
    Mutant(
        "tables-same-step-once",
        "hrl_torch/tables.py",
        "keep = (1.0 - alpha) ** n",
        "keep = (1.0 - alpha) * (n > 0) + (n == 0)",
        "several same-step updates of one entry count as one",
        (TABLES,),
    ),
    Mutant(
        "tables-row-stride",
        "hrl_torch/tables.py",
        "return learner * self.total + offset + state * n_cols + col",
        "return learner * self.total + offset + state + col",
        "table entries indexed without the row stride",
        (TABLES, MAXQ_EXACT),
    ),
    Mutant(
        "tables-masked-read",
        "hrl_torch/tables.py",
        "flat_index = torch.where(valid, flat_index, self.sentinel)",
        "flat_index = flat_index",
        "masked reads return real entries instead of 0",
        (TABLES,),
    ),
    Mutant(
        "epsilon-inverted",
        "hrl_torch/exploration.py",
        "explore = u[:, a] < self.epsilon(step)",
        "explore = u[:, a] >= self.epsilon(step)",
        "epsilon-greedy explores with probability 1 - epsilon",
        ("tests/test_exploration.py",),
    ),
    Mutant(
        "linear-schedule-direction",
        "hrl_torch/exploration.py",
        "return self.end if frac == 1.0 else self.start + frac * (self.end - self.start)",
        "return self.end if frac == 1.0 else self.start + frac * (self.start - self.end)",
        "a linear schedule moves away from its end value",
        ("tests/test_exploration.py",),
    ),
    Mutant(
        "uniform-choice-skips-last",
        "hrl_torch/exploration.py",
        "k = torch.minimum((u * count).long(), count - 1)  # the k-th available entry",
        "k = torch.minimum((u * count).long(), (count - 2).clamp_min(0))",
        "a random choice never picks the last available child",
        ("tests/test_exploration.py",),
    ),
    # ---------------------------------------------------------------- executor and graph
    Mutant(
        "executor-greedy-ignores-ancestors",
        "hrl_torch/executor.py",
        "_scatter_at(s.greedy, slot, greedy & parent_greedy)",
        "_scatter_at(s.greedy, slot, greedy)",
        "a child counts as greedy although an ancestor explored",
        ("tests/test_executor_flags.py", EXECUTOR, AVERAGE),
    ),
    Mutant(
        "executor-emits-for-popped-level",
        "hrl_torch/executor.py",
        "emit = active & ~is_prim & child_popped",
        "emit = active & ~is_prim & popped",
        "transitions emitted for the level that ended instead of its parent",
        (EXECUTOR, MAXQ_EXACT),
    ),
    Mutant(
        "executor-episode-end-not-terminal",
        "hrl_torch/executor.py",
        "terminal = (own | env_term[:, None]) & active & ~is_prim",
        "terminal = own & active & ~is_prim",
        "the end of the episode is not terminal for the subtasks on the stack",
        (EXECUTOR, MAXQ_EXACT),
    ),
    Mutant(
        "executor-undiscounted-sum",
        "hrl_torch/executor.py",
        "s.disc_reward += active * discount(self.gamma, s.time) * reward[:, None]",
        "s.disc_reward += active * reward[:, None]",
        "the discounted reward of a child is summed without discounting",
        (EXECUTOR, MULTISTEP),
    ),
    Mutant(
        "executor-shaping-undiscounted",
        "hrl_torch/executor.py",
        "s.internal += active * discount(self.gamma, s.time) * shaping.gather(1, node)",
        "s.internal += active * shaping.gather(1, node)",
        "shaping rewards summed without discounting",
        (EXECUTOR, MULTISTEP),
    ),
    Mutant(
        "executor-timeout-off-by-one",
        "hrl_torch/executor.py",
        "(s.inv_steps >= cfg.max_subtask_steps)",
        "(s.inv_steps > cfg.max_subtask_steps)",
        "the guard lets a subtask run one step more than its limit",
        (EXECUTOR,),
    ),
    Mutant(
        "graph-terminated-child-available",
        "hrl_torch/graph.py",
        "child_ok = initiable & ~blocked  # a child that would end at once is not available",
        "child_ok = initiable",
        "a child already terminated can be chosen",
        ("tests/test_graph.py",),
    ),
    Mutant(
        "graph-event-blocks",
        "hrl_torch/graph.py",
        "blocked = terminated & ~self.node_event",
        "blocked = terminated",
        "event-terminated subtasks are blocked from starting",
        ("tests/test_graph.py",),
    ),
    # ---------------------------------------------------------------- env base, checkpoints
    Mutant(
        "env-reward-on-reset-row",
        "hrl_torch/env.py",
        "reward = torch.where(was_done, zero, reward.float())",
        "reward = reward.float()",
        "a row that resets reports the reward of a step it never took",
        ("tests/envs/test_taxi.py",),
    ),
    Mutant(
        "env-truncation-late",
        "hrl_torch/env.py",
        "truncated = self.elapsed >= self.max_episode_steps",
        "truncated = self.elapsed > self.max_episode_steps",
        "episodes truncated one step after the time limit",
        ("tests/envs/test_taxi.py",),
    ),
    Mutant(
        "checkpoint-format-unchecked",
        "hrl_torch/checkpoint.py",
        'if not isinstance(state, dict) or state.get("format") != FORMAT:',
        "if not isinstance(state, dict):",
        "a file of another format loads as a checkpoint",
        ("tests/test_checkpoint.py", "tests/test_cli.py"),
    ),
    Mutant(
        "checkpoint-unsafe-load",
        "hrl_torch/checkpoint.py",
        'state = torch.load(path, map_location="cpu", weights_only=True)',
        'state = torch.load(path, map_location="cpu", weights_only=False)',
        "checkpoints unpickled with arbitrary code execution",
        ("tests/test_checkpoint.py", "tests/test_cli.py"),
    ),
    Mutant(
        "rng-stream-ignores-counter",
        "hrl_torch/rng.py",
        "self.counter += n",
        "self.counter += 0",
        "reserved random numbers are drawn again by the next step",
        ("tests/test_rng.py",),
    ),
    Mutant(
        "eval-rng-not-restarted",
        "hrl_torch/trainer.py",
        '        self._eval_rng().load_state_dict({"counter": 0})\n',
        "",
        "greedy evaluation's tie-breaking draws do not restart (evaluations differ)",
        ("tests/test_population.py",),
    ),
    Mutant(
        "agent-clock-frozen",
        "hrl_torch/agent.py",
        "self.clock += self.executor.envs_per_learner",
        "self.clock += 0",
        "the schedules' clock never advances (epsilon and step sizes stay at their start)",
        ("tests/test_population.py", "tests/test_cli.py"),
    ),
    Mutant(
        "heads-load-no-copy",
        "hrl_torch/heads.py",
        "view.copy_(state_dict[name])",
        "view.copy_(view)",
        "loading a checkpoint leaves the heads' tables as they were",
        ("tests/test_population.py",),
    ),
    Mutant(
        "stack-clear-keeps-done",
        "hrl_torch/stack.py",
        "        self.done.zero_()\n",
        "",
        "emptying the Task-Stacks keeps rows marked as waiting for a reset",
        ("tests/test_executor_flags.py", EXECUTOR),
    ),
    Mutant(
        "policy-heads-scores-dropped",
        "hrl_torch/learners/pg.py",
        "index[sel, :k], score[sel, :k] = out.index, out.score",
        "index[sel, :k] = out.index",
        "with several batches of PG heads, their likelihood-ratio terms are lost",
        ("tests/test_custom_head.py",) + PG,
    ),
    Mutant(
        "executor-stats-not-restored",
        "hrl_torch/executor.py",
        '        self.stats.load_state_dict(state["stats"])\n',
        "",
        "the subtask statistics since the last log are lost on resume (logs differ)",
        (RESUME,),
    ),
    Mutant(
        "evaluator-sums-not-restored",
        "hrl_torch/continuing.py",
        'self._sums = state["sums"].clone() if "sums" in state else None',
        "self._sums = None",
        "a continuing task's training throughput since the last log is lost on resume",
        (RESUME,),
    ),
    Mutant(
        "last-evaluation-not-restored",
        "hrl_torch/trainer.py",
        'if last.get("success"):  # the latest evaluation\'s details (a finished run resumed)',
        "if False:",
        "a finished run resumed has no result (its latest evaluation was not saved)",
        ("tests/test_checkpoint.py",),
    ),
    # ---------------------------------------------------------------- domain envs
    Mutant(
        "taxi-fuel-double-burn",
        "envs/taxi_fuel.py",
        "next_fuel = torch.where(moves, fuel - 1, fuel)",
        "next_fuel = torch.where(moves, fuel - 2, fuel)",
        "a move burns two units of fuel",
        ("tests/envs/test_taxi_fuel.py",),
    ),
    Mutant(
        "ship-duration-in-intervals",
        "envs/ship.py",
        "return reward, intervals * self.params.dt, ~active",
        "return reward, intervals, ~active",
        "ship steps report their duration in intervals, not seconds",
        ("tests/envs/test_ship.py",),
    ),
    Mutant(
        "agv-reward-without-rate",
        "envs/agv.py",
        "reward = r.assembly * self.delivered + r.part * parts_in + r.rate * tau",
        "reward = r.assembly * self.delivered + r.part * parts_in",
        "AGV rewards lose their per-time part (continuous time)",
        ("tests/envs/test_agv.py",),
    ),
    Mutant(
        "small-agv-no-delivery-flag",
        "envs/agv_small.py",
        "self.delivered = self.delivered_table[self.state, action]",
        "self.delivered = torch.zeros_like(self.delivered_table[self.state, action])",
        "the small AGV never reports a delivery",
        ("tests/envs/test_agv_small.py",),
    ),
]
