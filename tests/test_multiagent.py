"""Multi-agent execution (Chapter 6): decision epochs under tau_continue / tau_any / tau_all on
a hand-made two-agent case, cooperative abstractions, per-agent tables, bad input."""

import pytest
import torch

from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv
from hrl_torch.execution.transitions import Choice
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.multiagent.cooperative import (
    Cooperation,
    MultiAgentAgent,
    agent_rng,
    cooperative_graph,
)

WORK, WAIT = 0, 1


class Clock(MultiAgentBatchedEnv):
    """Discrete time, every agent acts every step; the shared field ``t`` counts the steps."""

    state_keys = ("t",)

    def __init__(self, seeds, envs, n_agents=2, horizon=30):
        super().__init__(seeds, envs, n_agents, 2)
        self.horizon = horizon
        self.t = torch.zeros(self.batch_size, dtype=torch.long)

    def _reset_rows(self, mask):
        self.t = self.t.masked_fill(mask, 0)

    def _step_all(self, action, acting):
        self.t = self.t + 1
        reward = (action == WORK).sum(1).float()
        return reward, torch.ones(self.batch_size), self.t >= self.horizon, acting | True

    def _observe(self):
        return {"t": self.t.clone()}

    def _observe_agents(self):
        return {"busy": torch.zeros(self.batch_size, self.n_agents, dtype=torch.long)}


def task(name: str, steps: int) -> Subtask:
    """Works for ``steps`` steps from its start (it remembers the step it started at)."""
    return Subtask(
        name,
        ["Work"],
        remember=lambda o: o["t"][:, None].float(),
        memory_size=1,
        terminated=lambda o, m: o["t"] - m[:, 0].long() >= steps,
    )


def graph() -> TaskGraph:
    root = Subtask("Root", ["TaskA", "TaskB", "Wait"])
    nodes = [root, task("TaskA", 2), task("TaskB", 3), Primitive("Work", WORK)]
    return TaskGraph("Root", [*nodes, Primitive("Wait", WAIT)], n_actions=2)


class AgentIndexPolicy:
    """Agent 0 always takes TaskA, agent 1 TaskB; below the root: the first child."""

    rng = None

    def new_step(self):
        pass

    def select(self, inst, ctx, available, step, push):
        child = torch.where(inst == 0, ctx.obs["agent"], 0)
        return Choice(child, torch.ones_like(child, dtype=torch.bool))


def root_choices(scheme: str, steps: int = 10):
    """Per step ``t`` (the decision at the observation after ``t`` steps), the agents that
    chose a child of the root and which."""
    g = graph()
    cooperation = Cooperation((("Root",),), wait="Wait")
    env = Clock([0], 1)
    learner = MaxQLearner(g, 2)
    agent = MultiAgentAgent(
        g,
        learner,
        EpsilonGreedy(0.0),
        agent_rng([0], 1, 2, "x"),
        1,
        2,
        cooperation=cooperation,
        scheme=scheme,
        learn=False,
    )
    agent.set_policy(AgentIndexPolicy())
    names = {g.index[n]: n for n in ("TaskA", "TaskB", "Wait")}
    seen = []

    def started():  # the root's children invoked by the latest act, per agent row
        ex = agent.executor
        new = ex.invoked[:, 1] & (ex.stack.inst[:, 1] >= 0)
        return {(j, names[int(ex.stack.node[j, 1])]) for j in range(2) if bool(new[j])}

    action = agent.start(env.reset())
    for _ in range(steps):
        seen.append(started())
        action, _ = agent.decide(env.step(action))
    return seen


def test_tau_continue_each_agent_decides_when_its_own_task_ends():
    # A takes 2 steps, B 3: agent 0 decides at 0, 2, 4, 6, 8; agent 1 at 0, 3, 6, 9
    seen = root_choices("continue")
    for t, made in enumerate(seen):
        expect = set()
        if t % 2 == 0:
            expect.add((0, "TaskA"))
        if t % 3 == 0:
            expect.add((1, "TaskB"))
        assert made == expect, (t, made)


def test_tau_any_interrupts_the_other_agent_when_the_first_task_ends():
    # A ends first, at 2: B is interrupted, both decide at 0, 2, 4, ...; B never finishes
    seen = root_choices("any")
    for t, made in enumerate(seen):
        expect = {(0, "TaskA"), (1, "TaskB")} if t % 2 == 0 else set()
        assert made == expect, (t, made)


def test_tau_all_the_first_agent_waits_for_the_other():
    # A ends at 2, agent 0 waits one step (Wait at 2), B ends at 3: both decide at 0, 3, 6, 9;
    # agent 0 waits at 2, 5, 8
    seen = root_choices("all")
    for t, made in enumerate(seen):
        expect = set()
        if t % 3 == 0:
            expect = {(0, "TaskA"), (1, "TaskB")}
        elif t % 3 == 2:
            expect = {(0, "Wait")}
        assert made == expect, (t, made)


def test_cooperative_subtask_tables_hold_the_others_actions():
    g = cooperative_graph(graph(), Cooperation((("Root",),)), n_agents=3)
    root = g.node("Root")
    # U_1 = {TaskA, TaskB, Wait} plus "no task": 4 codes for each of the 2 others
    assert root.n_states == 1 * 4**2
    idle = cooperative_graph(graph(), Cooperation((("Root",),), idle="Wait"), n_agents=3)
    assert idle.node("Root").n_states == 3**2


def test_unknown_cooperative_subtask_and_scheme_are_clear_errors():
    with pytest.raises(GraphError, match=r"cooperation level 0 names unknown subtasks \['Nope'\]"):
        cooperative_graph(graph(), Cooperation((("Nope",),)), 2)
    with pytest.raises(GraphError, match="Cooperation.wait 'Work' is not in U_1"):
        cooperative_graph(graph(), Cooperation((("Root",),), wait="Work"), 2)
    g = graph()
    with pytest.raises(ValueError, match="scheme must be 'continue', 'any' or 'all'"):
        MultiAgentAgent(
            g,
            MaxQLearner(g, 2),
            EpsilonGreedy(0.1),
            agent_rng([0], 1, 2, "x"),
            1,
            2,
            scheme="sometimes",
        )
    with pytest.raises(ValueError, match="the learner has 1 table sets, 2 needed"):
        MultiAgentAgent(g, MaxQLearner(g, 1), EpsilonGreedy(0.1), agent_rng([0], 1, 2, "x"), 1, 2)


def test_an_action_outside_an_agents_action_space_is_a_clear_error():
    env = Clock([0], 1)
    env.reset()
    with pytest.raises(ValueError, match=r"action 5 of agent 1 outside the action space \[0, 2\)"):
        env.step(torch.tensor([[0, 5]]))


def _trash_trainer(seeds, algo="cooperative"):
    import agents  # noqa: F401
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    opts = RunOptions(seeds=seeds, envs_per_learner=4, progress=False, tensorboard=False)
    return build_trainer(registry.get("trash"), algo, opts)


@pytest.mark.parametrize("algo", ["cooperative", "selfish"])
def test_a_population_of_multi_agent_learners_equals_separate_runs(algo):
    together = _trash_trainer([3, 8], algo)
    for _ in range(150):
        together.train_step()
    q = together.learner.C.data  # [P * n table sets, ...]: seed p's agent j at p * 2 + j
    assert q.shape[0] == 4
    for p, seed in enumerate([3, 8]):
        alone = _trash_trainer([seed], algo)
        for _ in range(150):
            alone.train_step()
        assert torch.equal(alone.learner.C.data, q[2 * p : 2 * p + 2]), seed
        assert torch.equal(alone.learner.V.data, together.learner.V.data[2 * p : 2 * p + 2])
    assert together.learner.C.data.ne(-10.0).any()  # learned: not vacuous


def test_trash_training_restarts_and_evaluation_runs_the_long_run():
    trainer = _trash_trainer([0], "selfish")
    assert trainer.env.max_episode_steps == 100
    assert trainer.eval_env is not None and trainer.eval_env.max_episode_steps is None
    for _ in range(101):
        trainer.train_step()
    assert trainer.env.elapsed.max() < 100  # every row restarted once


def test_four_agv_joint_root_table_has_the_texts_shape():
    from agents.four_agv import COOPERATION, four_agv_hierarchy

    g = cooperative_graph(four_agv_hierarchy(), COOPERATION, 4)
    root = g.node("Root")
    # 256 job-availability states x the other three AGVs' U_1 tasks (9 each, Idle included)
    assert root.n_states == 256 * 9**3 and len(root.children_names) == 9
    assert g.node("DM_1").n_states == 7_200 and g.node("DA_1").n_states == 3_600
    assert g.node("Nav_W_1").n_states == 100


def test_the_joint_chain_of_a_fixed_joint_policy_has_the_models_gain():
    # two robots each following a fixed random table over the joint state (a flat graph whose
    # root picks the primitive): the chain explored through the executor must have exactly
    # the gain of the model's own chain for that joint policy
    from envs.trash import TrashEnv, decode, exact_model
    from hrl_torch.analysis import markov_chain_gain
    from hrl_torch.analysis.joint import FirstGreedy, chain_gain, joint_chain
    from hrl_torch.learners import RuleLearner

    model = exact_model(2)
    table = torch.randint(0, 7, (model.n_states, 2), generator=torch.Generator().manual_seed(3))
    root = Subtask("Root", [f"a{k}" for k in range(7)])
    g = TaskGraph("Root", [root, *(Primitive(f"a{k}", k) for k in range(7))], n_actions=7)

    def rule(rows):
        return lambda obs: table[obs["observation"], obs["agent"]]

    learner = RuleLearner(g, 2, rule)

    def make_agent(m):
        rng = agent_rng([0], m, 2, "x")
        return MultiAgentAgent(g, learner, FirstGreedy(), rng, m, 2, learn=False, evaluate=True)

    def observe(states):
        env = TrashEnv([0], len(states), 2)
        d = decode(states, 2)
        env.location, env.carrying, env.cans = d["location"], d["carrying"].bool(), d["cans"]
        env.cans = env.cans.bool()
        zero = torch.zeros(len(states))
        flag = zero.bool()
        return env._output(zero, zero, flag, flag, flag, torch.zeros(len(states), 2))

    start = model.start_distribution()
    chain = joint_chain(
        make_agent, model.next_state, model.prob, model.reward, model.joint_action, observe, start
    )
    p, r = model.chain(model.joint_action(table))
    expected = float(start @ markov_chain_gain(p, r).gain)
    assert abs(chain_gain(chain) - expected) < 1e-8
    assert len(chain.reward) > 100  # the chain went somewhere
