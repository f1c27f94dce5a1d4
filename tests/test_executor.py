import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tensordict import TensorDict

from hrl_torch.common.rng import BatchRNG
from hrl_torch.execution.executor import ExecutorConfig, HierarchicalExecutor, SubtaskTimeoutError
from hrl_torch.execution.transitions import Choice
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner, ValuePolicy
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.training.agent import with_values
from tests.helpers import random_hierarchy, random_table_env


def run_checked(graph, env, steps, check_step):
    learner = MaxQLearner(graph, env.n_learners)
    policy = ValuePolicy(
        learner, EpsilonGreedy(0.5), BatchRNG(env.seeds, env.envs_per_learner, "x")
    )
    ex = HierarchicalExecutor(
        graph,
        env.batch_size,
        env.envs_per_learner,
        config=ExecutorConfig(max_subtask_steps=50, on_timeout="abort"),
    )
    rows = env.learner_of_row()
    ctx = graph.context(env.reset(), rows)
    learner.evaluate(ctx)
    ex.act(ctx, policy, 0)
    for _ in range(steps):
        before = (ex.stack.inst.clone(), ex.stack.top.clone())
        td = env.step(ex._action)
        ctx = graph.context(td, rows)
        learner.evaluate(ctx)
        batch = ex.observe(td, ctx)
        check_step("observe", ex, ctx, td, batch, before)
        learner.update(with_values(batch, ctx), 0)
        before = (ex.stack.inst.clone(), ex.stack.top.clone(), ex.stack.child.clone())
        ex.act(ctx, policy, 0)
        check_step("act", ex, ctx, td, None, before)


def check_invariants(graph):
    def check(phase, ex, ctx, td, batch, before):
        b_idx = torch.arange(ex.batch_size)
        if phase == "act":
            live = ex.stack.top >= 0
            assert ((ex.stack.top + 1) <= graph.max_levels).all()
            top_node = graph.inst_node[ex.stack.inst[b_idx, ex.stack.top.clamp_min(0)]]
            # after pushing, a primitive is on top of every live stack
            assert graph.node_is_primitive[top_node][live].all()
            for b in live.nonzero().squeeze(1).tolist():
                t = int(ex.stack.top[b])
                assert int(ex.stack.inst[b, 0]) == 0
                for k in range(t):
                    inst = int(ex.stack.inst[b, k])
                    assert int(ex.stack.inst[b, k + 1]) == int(
                        graph.inst_children[inst, ex.stack.child[b, k]]
                    )
                    # no live subtask sits in its own terminal set
                    assert not bool(ctx.terminated[b, graph.inst_node[inst]])
            # empty stacks only for rows whose episode just ended
            assert (live | ex.stack.done).all()
            # act only pushes: the levels left after the pops keep their instances, and the
            # ones below the top their children
            stack, top, child = before
            for b in (top >= 0).nonzero().squeeze(1).tolist():
                t = int(top[b])
                assert torch.equal(ex.stack.inst[b, : t + 1], stack[b, : t + 1])
                assert torch.equal(ex.stack.child[b, :t], child[b, :t])
            return
        stack, top = before
        real = ~td["is_init"]
        for b in real.nonzero().squeeze(1).tolist():
            t = int(top[b])
            nodes = graph.inst_node[stack[b, : t + 1]]
            own = ctx.terminated[b, nodes] | td["terminated"][b]
            ends = own.clone()
            ends[t] = True  # the primitive always completes
            if bool(td["terminated"][b]) or bool(td["truncated"][b]):
                ends[:] = True
            first = int(ends.nonzero()[0])
            # termination pops exactly the first terminated level and everything above it
            assert int(ex.stack.top[b]) == first - 1
            emitted = batch["level", "valid"][b].nonzero().squeeze(1).tolist()
            assert emitted == list(range(max(first - 1, 0), t))
            for lvl in emitted:
                assert bool(batch["level", "terminal"][b, lvl]) == bool(own[lvl])
                assert bool(batch["level", "child_done"][b, lvl]) == bool(
                    own[lvl + 1] or lvl + 1 == t
                )

    return check


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n_subtasks=st.integers(1, 5),
    n_states=st.integers(2, 12),
    n_actions=st.integers(1, 4),
    seed=st.integers(0, 10_000),
)
def test_executor_invariants_on_random_hierarchies(n_subtasks, n_states, n_actions, seed):
    graph = random_hierarchy(n_subtasks, n_states, n_actions, seed)
    env = random_table_env(
        n_states, n_actions, seed, envs_per_learner=6, seeds=(seed, seed + 1), max_episode_steps=40
    )
    run_checked(graph, env, 60, check_invariants(graph))


def test_runaway_subtask_raises_or_aborts():
    # a subtask whose termination never holds
    loop = Subtask("Loop", ["a0"], terminated=lambda o: o["observation"] < 0)
    graph = TaskGraph("Root", [Subtask("Root", ["Loop"]), loop, Primitive("a0", 0)], n_actions=1)
    env = random_table_env(5, 1, 0, terminal_frac=0.0, envs_per_learner=2)
    learner = MaxQLearner(graph, 1)
    policy = ValuePolicy(learner, EpsilonGreedy(0.1), BatchRNG([0], 2, "x"))
    for mode in ("raise", "abort"):
        ex = HierarchicalExecutor(
            graph, 2, 2, config=ExecutorConfig(max_subtask_steps=7, on_timeout=mode)
        )
        ctx = graph.context(env.reset())
        learner.evaluate(ctx)
        ex.act(ctx, policy, 0)
        if mode == "raise":
            with pytest.raises(SubtaskTimeoutError, match="'Loop' ran 7 primitive steps"):
                for _ in range(10):
                    td = env.step(ex._action)
                    ctx = graph.context(td)
                    learner.evaluate(ctx)
                    ex.observe(td, ctx)
                    ex.act(ctx, policy, 0)
        else:
            tops, root_ends = [], []
            for _ in range(20):
                td = env.step(ex._action)
                ctx = graph.context(td)
                learner.evaluate(ctx)
                batch = ex.observe(td, ctx)
                # the aborted Loop gives its parent no completed child
                assert not (
                    batch["level", "valid"][:, 0] & batch["level", "child_done"][:, 0]
                ).any()
                tops.append(ex.stack.top.tolist())
                root_ends.append(batch["level", "valid"][:, 0].tolist())
                ex.act(ctx, policy, 0)
            # by hand: after every step a0 (level 2) pops, leaving Loop on top (level 1); Loop's
            # 7th step reaches the guard (inv_steps >= 7), so steps 7 and 14 also pop Loop,
            # leaving Root on top (level 0) with a transition (its child ended, aborted), and
            # the next act pushes Loop afresh; both rows run in lockstep
            cycle = [1] * 6 + [0]
            expected_top = (cycle * 3)[:20]
            assert tops == [[t, t] for t in expected_top]
            assert root_ends == [[t == 0, t == 0] for t in expected_top]
            # Loop pushed 3 times per row (step 0, after step 7, after step 14), 2 rows
            assert int(ex.stats.calls[0, graph.index["Loop"]]) == 6
            # finished invocations, successes and lengths: a0 ends (succeeds) every step after
            # 1 step; Loop is cut by the guard twice per row after 7 steps (no success); the
            # root never ends, so it has no length
            stats = {k: getattr(ex.stats, k)[0].tolist() for k in ex.stats.FIELDS}
            root, lp, a0 = (graph.index[n] for n in ("Root", "Loop", "a0"))
            assert [stats[k][a0] for k in ("ends", "successes", "durations")] == [40, 40, 40]
            assert [stats[k][lp] for k in ("ends", "successes", "durations")] == [4, 0, 28]
            assert [stats[k][root] for k in ("ends", "successes", "durations")] == [0, 0, 0]


def test_no_available_child_is_a_clear_error():
    dead = Subtask(
        "Dead", ["a0"], child_mask=lambda o: torch.zeros(o.batch_size[0], 1, dtype=torch.bool)
    )
    graph = TaskGraph("Root", [Subtask("Root", ["Dead"]), dead, Primitive("a0", 0)], n_actions=1)
    env = random_table_env(4, 1, 0, terminal_frac=0.0)
    learner = MaxQLearner(graph, 1)
    policy = ValuePolicy(learner, EpsilonGreedy(0.1), BatchRNG([0], 1, "x"))
    ex = HierarchicalExecutor(graph, 1, 1)
    ctx = graph.context(env.reset())
    learner.evaluate(ctx)
    from hrl_torch.hierarchy.subtask import GraphError

    with pytest.raises(GraphError, match="'Dead' has no available child"):
        ex.act(ctx, policy, 0)


def test_nan_reward_is_a_clear_error():
    graph = random_hierarchy(2, 4, 2, 0)
    env = random_table_env(4, 2, 0, terminal_frac=0.0)
    env.reward_table[:] = float("nan")
    with pytest.raises(ValueError, match="returned reward nan and duration"):
        run_checked(graph, env, 3, lambda *a: None)


def test_observe_and_act_never_write_into_the_stack_they_were_given():
    # the executor replaces its stack at every call; a stack handed out earlier (a rollout
    # TensorDict holds one per frame) keeps its values
    graph = random_hierarchy(3, 6, 3, 1)
    env = random_table_env(6, 3, 1, envs_per_learner=4, seeds=(1, 2), max_episode_steps=30)
    learner = MaxQLearner(graph, env.n_learners)
    policy = ValuePolicy(learner, EpsilonGreedy(0.5), BatchRNG(env.seeds, 4, "x"))
    config = ExecutorConfig(max_subtask_steps=20, on_timeout="abort", record_visited=3)
    ex = HierarchicalExecutor(graph, env.batch_size, 4, gamma=0.9, config=config)
    rows = env.learner_of_row()
    ctx = graph.context(env.reset(), rows)
    learner.evaluate(ctx)
    ex.act(ctx, policy, 0)
    pops = 0
    for _ in range(40):
        td = env.step(ex._action)
        ctx = graph.context(td, rows)
        learner.evaluate(ctx)
        for call in ("observe", "act"):
            old = ex.stack
            kept = old.state_dict()  # cloned
            if call == "observe":
                batch = ex.observe(td, ctx)
                learner.update(with_values(batch, ctx), 0)
                pops += int((ex.stack.inst < 0).sum() - (old.inst < 0).sum())
            else:
                ex.act(ctx, policy, 0)
            assert ex.stack is not old
            for key, value in old.to_dict().items():
                assert torch.equal(value, kept[key]), (call, key)
    assert pops > 0  # stacks did pop (the test saw changes to keep out of the old stack)


@pytest.mark.parametrize("per_instance", [False, True])
def test_value_policy_choosing_for_all_instances_equals_choosing_level_by_level(per_instance):
    # ValuePolicy chooses at every choosing instance at once, the instance at depth d reading
    # the uniforms of level d: the same choices as asking the learner level by level
    from agents.taxi import taxi_hierarchy
    from envs.taxi import TaxiEnv
    from hrl_torch.training.agent import HierarchicalAgent

    def run(all_at_once):
        graph, seeds = taxi_hierarchy(), [3, 4]
        env = TaxiEnv(seeds, 3)
        learner = MaxQLearner(graph, len(seeds), per_instance=per_instance)
        rng = BatchRNG(seeds, 3, "explore")
        agent = HierarchicalAgent(graph, learner, EpsilonGreedy(0.3), rng, 3)
        assert agent.policy.all_at_once
        agent.policy.all_at_once = all_at_once
        actions = [agent.start(env.reset())]
        for _ in range(150):
            actions.append(agent.step(env.step(actions[-1])))
        return torch.stack(actions), learner.C.store

    at_once, per_level = run(True), run(False)
    assert torch.equal(at_once[0], per_level[0])
    assert torch.equal(at_once[1], per_level[1])


def test_a_continuous_primitive_takes_the_action_chosen_with_its_push():
    # Root calls the continuous primitive Move directly (row 0) or through Sub (row 1, one
    # level deeper): the env gets the action value chosen with Move's push, however deep the
    # stacks can grow above it
    nodes = [
        Subtask("Root", ["Move", "Sub"]),
        Subtask("Sub", ["Move"]),
        Primitive("Move", action_dim=1),
    ]
    graph = TaskGraph("Root", nodes)

    class ByRow:
        def new_step(self):
            pass

        def select(self, inst, ctx, available, step, push):
            row = torch.arange(inst.shape[0])
            child = torch.where(inst == 0, row % 2, 0)
            action = (10.0 * (push + 1) + row)[:, None]  # the push level and the row
            return Choice(child, torch.ones_like(child, dtype=torch.bool), action)

    ex = HierarchicalExecutor(graph, 2, 2)
    action = ex.act(graph.context(TensorDict({}, batch_size=[2])), ByRow(), 0)
    assert ex.stack.top.tolist() == [1, 2]
    assert action[:, 0].tolist() == [10.0, 21.0]


@pytest.mark.parametrize(
    "domain, algo", [("taxi", "maxq-q"), ("taxi-fuel-earlier", "hpgrl"), ("ship-steering-earlier",
    "hybrid")]
)
def test_choosing_for_the_choosing_rows_only_gives_the_same_run(domain, algo, monkeypatch):
    # large CPU batches choose level by level for the rows that choose at a level only
    # (policy.select_rows, their random numbers alone drawn): the same choices, tables and
    # stacks as choosing for every row
    import agents  # noqa: F401
    from hrl_torch.learners.base import ValuePolicy
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    monkeypatch.setattr(ValuePolicy, "ALL_AT_ONCE_LIMIT", 0)  # (value learners: level by level)

    def run(compact_from):
        monkeypatch.setattr(HierarchicalExecutor, "COMPACT_ROWS", compact_from)
        opts = RunOptions(seeds=[3, 4], envs_per_learner=5, progress=False, tensorboard=False)
        trainer = build_trainer(registry.get(domain), algo, opts)
        for _ in range(60):
            trainer.train_step()
        return trainer.learner.state_dict(), trainer.executor.stack.state_dict()

    (every_learner, every_stack), (some_learner, some_stack) = run(10**9), run(1)
    for k, v in every_learner.items():
        if isinstance(v, torch.Tensor):
            assert torch.equal(v, some_learner[k]), k
    for k in ("inst", "child", "start_state", "reward", "score_index", "score_value"):
        assert torch.equal(every_stack[k], some_stack[k]), k


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_level_that_chooses_a_child_starts_fresh_sums_at_the_state_it_chose_in(seed):
    # after act, every level from the old top (a subtask left on top choosing its next child;
    # the root of a starting row) up to the primitive's parent chose a child this step: its
    # sums restart and its start state is its abstract state now; the levels below keep theirs
    graph = random_hierarchy(4, 8, 3, seed)
    env = random_table_env(8, 3, seed, envs_per_learner=6, seeds=(seed, seed + 1))
    fields = ("steps", "time", "reward", "start_state")
    kept_before, rechosen = {}, []

    def check(phase, ex, ctx, td, batch, before):
        if phase == "observe":  # (what observe left: the levels act may keep)
            kept_before.update({k: getattr(ex.stack, k).clone() for k in fields})
            return
        old_top, top = before[1], ex.stack.top
        for b in (top >= 1).nonzero().squeeze(1).tolist():
            chose = range(max(int(old_top[b]), 0), int(top[b]))
            for k in chose:
                node = graph.inst_node[ex.stack.inst[b, k]]
                assert int(ex.stack.start_state[b, k]) == int(ctx.abstract[b, node])
                assert [float(getattr(ex.stack, f)[b, k]) for f in fields[:3]] == [0, 0, 0]
            for k in range(int(old_top[b])):
                for f in fields:
                    assert getattr(ex.stack, f)[b, k] == kept_before[f][b, k], (f, b, k)
            rechosen.append(int(old_top[b]) >= 0 and len(chose) > 0)

    run_checked(graph, env, 60, check)
    assert any(rechosen)  # (subtasks on top did choose their next child)
