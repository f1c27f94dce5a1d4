"""Sequential broadcast within a decision epoch (``Cooperation.broadcast``, Section 6.5's rule).

On the hand-made two-agent clock of ``tests/test_multiagent.py`` (TaskA lasts 2 steps, TaskB 3;
agent 0 always takes TaskA, agent 1 TaskB): the code each agent saw when its root child started
is the root's start state (the root has one state of its own, so its abstract state is the
others' ``U_1`` code: 0 TaskA, 1 TaskB, 2 Wait, 3 none).
"""

import hashlib

import pytest
import torch

import agents  # noqa: F401 (registers the built-in domains)
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.multiagent.cooperative import (
    Cooperation,
    MultiAgentAgent,
    agent_rng,
    cooperative_graph,
)
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from tests.test_multiagent import AgentIndexPolicy, Clock, graph

NONE, TASK_A, TASK_B = 3, 0, 1


def seen_codes(broadcast: str, steps: int = 7) -> list[list[int]]:
    """Per step, the code each agent saw when its current root child started."""
    cooperation = Cooperation((("Root",),), wait="Wait", broadcast=broadcast)
    g = cooperative_graph(graph(), cooperation, 2)
    env = Clock([0], 1)
    agent = MultiAgentAgent(
        g,
        MaxQLearner(g, 2),
        EpsilonGreedy(0.0),
        agent_rng([0], 1, 2, "x"),
        1,
        2,
        cooperation=cooperation,
        learn=False,
        transitions=True,  # (the stacks keep the start states only where transitions are made)
    )
    agent.set_policy(AgentIndexPolicy())
    action = agent.start(env.reset())
    seen = [agent.executor.stack.start_state[:, 0].tolist()]
    for _ in range(steps - 1):
        action, _ = agent.decide(env.step(action))
        seen.append(agent.executor.stack.start_state[:, 0].tolist())
    return seen


def test_a_later_agent_sees_the_fresh_choice_of_an_earlier_one():
    seen = seen_codes("sequential")
    # t=0 both choose: agent 0 sees none, agent 1 sees agent 0's TaskA just chosen
    assert seen[0] == [NONE, TASK_A]
    # t=2 agent 0 alone chooses again, seeing TaskB running; t=3 agent 1 sees TaskA running
    assert seen[2] == [TASK_B, TASK_A] and seen[3] == [TASK_B, TASK_A]
    # t=6 both tasks end together: agent 0 sees agent 1 without a task, agent 1 the fresh TaskA
    assert seen[6] == [NONE, TASK_A]


def test_simultaneous_broadcast_keeps_the_previous_steps_tasks():
    seen = seen_codes("simultaneous")
    assert seen[0] == [NONE, NONE]  # neither sees the other's choice at the start
    assert seen[6] == [TASK_B, TASK_A]  # each sees the other's task that just ended


def test_an_unknown_broadcast_is_a_clear_error():
    with pytest.raises(ValueError, match="broadcast"):
        seen_codes("instant")


@pytest.mark.parametrize("broadcast", ["sequential", "simultaneous"])
def test_sequential_targets_read_the_root_value_at_the_seen_code(broadcast):
    # the transition values of a step where both choose are the values at the codes seen
    # (simultaneous: agent 0 read agent 1's just-ended TaskB instead, another value)
    cooperation = Cooperation((("Root",),), wait="Wait", broadcast=broadcast)
    g = cooperative_graph(graph(), cooperation, 2)
    learner = MaxQLearner(g, 2)
    learner.C.store.copy_(torch.randn_like(learner.C.store))  # codes give different values
    env = Clock([0], 1)
    agent = MultiAgentAgent(
        g, learner, EpsilonGreedy(0.0), agent_rng([0], 1, 2, "x"), 1, 2, cooperation=cooperation
    )
    agent.set_policy(AgentIndexPolicy())
    action = agent.start(env.reset())
    for _ in range(6):  # t=6: both choose
        action, batch = agent.decide(env.step(action))
    obs = agent.ctx.obs.clone(False)  # s' with the codes the agents saw when choosing
    obs.set("others_U1", torch.tensor([NONE, TASK_A]))
    ctx = g.context(obs, agent.rows)
    learner.evaluate(ctx)
    root = 0
    same = torch.equal(batch["values"]["V"][:, root], ctx.values["V"][:, root])
    assert same == (broadcast == "sequential")


@pytest.mark.parametrize("domain", ["trash", "two-taxi-earlier", "four-agv-earlier"])
def test_static_rounds_learn_the_tables_of_early_stopping(domain, monkeypatch):
    """All n - 1 re-choosing rounds (no host read) equal stopping when no code changed."""
    import hrl_torch.multiagent.broadcast
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    tables = {}
    for static in (False, True):
        monkeypatch.setattr(hrl_torch.multiagent.broadcast, "STATIC_ROUNDS", static)
        opts = RunOptions(seeds=[0, 1], envs_per_learner=4, progress=False, check_env=False)
        opts.eval_episodes = 0
        trainer = build_trainer(registry.get(domain), "cooperative", opts)
        for _ in range(60):
            trainer.train_step()
        tables[static] = trainer.learner.state_dict()
    for key, value in tables[False].items():
        assert torch.equal(value, tables[True][key]), key


@pytest.mark.parametrize(
    ("domain", "algo"), [("trash", "cooperative"), ("two-taxi-earlier", "com-1")]
)
def test_recoded_contexts_learn_the_tables_of_contexts_computed_anew(domain, algo, monkeypatch):
    """The re-choosing rounds' contexts moved by the codes (``RECODE``) equal computed ones.

    (Also across the change: on 11345d5 the tables of 80 steps of 2 seeds x 4 envs of trash,
    two-taxi-earlier, two-taxi-earlier com-1, four-agv-earlier and four-agv Cooperative HRL
    hashed to
    5d95f490672a2e41, 2e06772f7b78ef26, 3cd4140a57b3ca38, d984a93661f524d0, 284cd707ea11ad5c,
    and so they do after it: ``benchmarks/side_by_side.py hashes``.)
    """
    import hrl_torch.multiagent.broadcast
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    tables = {}
    for recode in (False, True):
        monkeypatch.setattr(hrl_torch.multiagent.broadcast, "RECODE", recode)
        opts = RunOptions(seeds=[0, 1], envs_per_learner=4, progress=False, check_env=False)
        opts.eval_episodes = 0
        trainer = build_trainer(registry.get(domain), algo, opts)
        for _ in range(60):
            trainer.train_step()
        tables[recode] = trainer.learner.state_dict()
    for key, value in tables[False].items():
        assert torch.equal(value, tables[True][key]), key


def test_trash_cooperative_learns_the_tables_it_learned_before_the_step_was_cut():
    # issue 38: one evaluation before the choices, the targets' context only where a learning
    # level reads it; the learner's state after 150 steps of 2 seeds x 4 envs hashes as it did
    # on f3a1bd5 (and on bf82c46's successors up to 703849c)
    opts = RunOptions(
        seeds=[0, 1], envs_per_learner=4, progress=False, tensorboard=False, check_env=False
    )
    opts.eval_episodes = 0
    trainer = build_trainer(registry.get("trash"), "cooperative", opts)
    for _ in range(150):
        trainer.train_step()
    h = hashlib.sha256()
    for key, value in sorted(trainer.learner.state_dict().items()):
        h.update(key.encode())
        h.update(value.detach().contiguous().reshape(-1).view(torch.uint8).numpy().tobytes())
    assert h.hexdigest()[:16] == "98b634108d725701"
