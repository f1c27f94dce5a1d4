import torch
from tensordict import TensorDict

from agents.trash import COLLECT_STATES, ROOT_STATES, U1, trash_com_hierarchy, trash_hierarchy
from envs.trash import CANS, DUMP, N_ACTIONS, PUT, WAIT, TrashEnv
from hrl_torch.common.rng import BatchRNG
from hrl_torch.execution.executor import ExecutorConfig, HierarchicalExecutor
from hrl_torch.execution.transitions import LEVEL

torch.set_num_threads(1)


class RandomChildren:
    """An executor policy: uniform among the available children."""

    def __init__(self, rng):
        self.rng = rng

    def new_step(self):
        pass

    def select(self, inst, ctx, available, step, push):
        u = self.rng.uniform(available.shape[1])
        choice = torch.where(available, u, -1.0).argmax(-1)
        return choice, torch.zeros_like(inst, dtype=torch.bool)


def random_rollout(graph, env, steps, seed=0):
    """Every agent row runs its own Task-Stack with random choices, ``steps`` env steps.

    ``graph.context`` raises on an abstract state out of range and the executor on a subtask
    that must choose without an available child; on top of that every subtask that is not in a
    terminal state (so could be on top of a stack) must have an available child in every row.
    Returns the ``(parent, child)`` names of every child that ended by its own termination.
    """
    n_rows = env.batch_size * env.n_agents
    learner = env.learner_of_agent_row()
    ex = HierarchicalExecutor(
        graph,
        n_rows,
        learner=learner,
        config=ExecutorConfig(max_subtask_steps=1000, on_timeout="abort"),
    )
    policy = RandomChildren(BatchRNG([seed], n_rows, "choices"))
    subtasks = graph.subtasks()
    ended = set()

    def context(td):
        rows = env.agent_rows(td)
        ctx = graph.context(rows, learner)
        could_be_on_top = ~ctx.blocked[:, subtasks]
        has_child = ctx.available[:, subtasks].any(-1)
        assert (has_child | ~could_be_on_top).all()
        return rows, ctx

    _, ctx = context(env.reset())
    action = ex.act(ctx, policy, 0)
    for t in range(steps):
        rows, ctx = context(env.step(action.view(env.batch_size, env.n_agents)))
        level = ex.observe(rows, ctx)[LEVEL]
        done = level["valid"] & level["child_done"]
        pairs = zip(level["node"][done].tolist(), level["child"][done].tolist(), strict=True)
        for node, child in pairs:
            ended.add((graph.names[node], graph.nodes[node].children_names[child]))
        action = ex.act(ctx, policy, t + 1)
    return ended


def obs(**fields):
    """One agent row with the given fields (others 0)."""
    keys = ("location", "carrying", "own_state", "t1_full", "t2_full", "dumped", "last_action")
    values = {k: torch.tensor([fields.get(k, 0)]) for k in keys}
    return TensorDict(values, batch_size=[1])


def test_graph_of_figure_6_1():
    g = trash_hierarchy()
    assert g.node("Root").children_names == U1 == ("CollectT1", "CollectT2", "Wait")
    assert g.node("CollectT1").children_names == ("NavT1", "NavDump", "Pick", "Put")
    assert g.node("CollectT2").children_names == ("NavT2", "NavDump", "Pick", "Put")
    for nav in ("NavT1", "NavT2", "NavDump"):
        assert g.node(nav).children_names == ("North", "South", "East", "West")
        assert g.node(nav).n_states == 12
    assert g.node("Root").n_states == ROOT_STATES == 96
    assert g.node("CollectT1").n_states == COLLECT_STATES == 48
    assert g.node("Put").n_states == 24 and g.node("Pick").n_states == 1
    assert g.node("Put").action == PUT and g.node("Wait").action == WAIT
    assert g.n_actions == N_ACTIONS and g.max_levels == 4  # Root / Collect / Nav / primitive
    # NavDump is shared: one subtask, two instances
    paths = [g.instance_path(k) for k in range(g.n_instances)]
    assert "Root/CollectT1/NavDump" in paths and "Root/CollectT2/NavDump" in paths


def test_graph_of_figure_6_9():
    g = trash_com_hierarchy()
    assert g.node("Root").children_names == ("Com", "NotCom")
    assert g.node("Com").children_names == g.node("NotCom").children_names == U1
    assert g.node("Com").n_states == ROOT_STATES
    assert g.max_levels == 5
    ctx = g.context(
        TensorDict.cat(
            [obs(dumped=1), obs(last_action=WAIT), obs(last_action=PUT), obs(carrying=1)]
        )
    )
    # no termination of their own: the COM agent ends them after one U_1 task
    assert not ctx.terminated[:, g.index["Com"]].any()
    assert not ctx.blocked[:, g.index["NotCom"]].any()


def test_terminations_and_abstractions_by_hand():
    g = trash_hierarchy()
    rows = TensorDict.cat(
        [
            obs(location=CANS[0], t1_full=1),  # at T1, trash there
            obs(location=DUMP, carrying=1),  # at the Dump with a load, T1 empty
            obs(location=5),  # nothing anywhere: only Wait at Root
        ]
    )
    ctx = g.context(rows)
    col = g.index
    assert ctx.terminated[:, col["CollectT1"]].tolist() == [False, False, True]
    assert ctx.terminated[:, col["NavT1"]].tolist() == [True, False, False]
    assert ctx.terminated[:, col["NavDump"]].tolist() == [False, True, False]
    assert ctx.abstract[:, col["CollectT1"]].tolist() == [1, (DUMP * 2 + 1) * 2, 5 * 2 * 2]
    assert ctx.abstract[:, col["Put"]].tolist() == [0, DUMP * 2 + 1, 10]
    # Root: T2 is empty in every row; a loaded robot's Collect subtasks are never terminal
    root = ctx.available[:, col["Root"], :3]
    assert root.tolist() == [[True, False, True], [True, True, True], [False, False, True]]


def test_random_hierarchical_rollouts_stay_in_range_and_never_get_stuck():
    env = TrashEnv([0, 1], 16, refill_prob=0.2)
    ended = random_rollout(trash_hierarchy(), env, 300)
    for pair in [
        ("Root", "CollectT1"),
        ("Root", "CollectT2"),
        ("Root", "Wait"),
        ("CollectT1", "NavT1"),
        ("CollectT1", "NavDump"),
        ("CollectT2", "Pick"),
        ("CollectT2", "Put"),
        ("NavDump", "North"),
    ]:
        assert pair in ended, pair


def test_random_rollouts_of_the_communication_graph():
    env = TrashEnv([2], 32, refill_prob=0.2)
    ended = random_rollout(trash_com_hierarchy(), env, 300, seed=1)
    # without the COM agent Com / NotCom never end: only their children do
    assert ("Root", "Com") not in ended and ("Root", "NotCom") not in ended
    for pair in [
        ("Com", "CollectT1"),
        ("NotCom", "CollectT2"),
        ("Com", "Wait"),
        ("CollectT1", "Put"),
    ]:
        assert pair in ended, pair


def test_the_cooperative_algorithm_starts_its_joint_root_optimistic_and_the_rest_pessimistic():
    from hrl_torch.runs import registry
    spec = registry.get("trash").algos["cooperative"]
    learner = spec.make_learner(spec.make_graph(), 2)
    assert bool((learner.heads["Root"]["C"] == 0).all())  # every joint choice gets tried
    assert bool((learner.heads["CollectT1"]["C"] == -10).all())
    selfish = registry.get("trash").algos["selfish"]
    assert bool((selfish.make_learner(selfish.make_graph(), 2).heads["Root"]["C"] == -10).all())
