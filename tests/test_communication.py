"""COM-Cooperative HRL (Section 6.5): the communication choice, its cost and its messages."""

import pytest
import torch

from agents.two_taxi import COM_COOPERATION, U1, com_graph
from envs.two_taxi import NO_PASSENGER, TwoTaxiEnv
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy, Greedy
from hrl_torch.multiagent.cooperative import (
    Communication,
    Cooperation,
    MultiAgentAgent,
    agent_rng,
    cooperative_graph,
)

G, B = 1, 3  # station indices (R, G, Y, B)
CODE = {name: k for k, name in enumerate(U1)}  # the others' U_1 codes (Wait: no task yet)


class BusyGAndB(TwoTaxiEnv):
    """No arrivals; passengers (for R) wait at G and B from the start; taxis at fixed cells."""

    def __init__(self):
        super().__init__([0], 1, mean_interarrival=float("inf"))

    def _reset_rows(self, mask):
        super()._reset_rows(mask)
        self.taxi_loc[:] = torch.tensor([12, 7])
        self.station_dest[:] = NO_PASSENGER
        self.station_dest[:, G] = 0
        self.station_dest[:, B] = 0


def _agent(cost: float, **options) -> tuple[MultiAgentAgent, object]:
    """Two greedy taxis communicating at ``cost`` (``options``: of ``Communication``)."""
    g = com_graph()
    learner = MaxQLearner(g, 2)
    agent = MultiAgentAgent(
        g,
        learner,
        Greedy(),
        agent_rng([0], 1, 2, "com"),
        1,
        2,
        cooperation=COM_COOPERATION,
        communication=Communication(cost=cost, **options),
        learn=False,
    )
    return agent, learner


def _hand_set_tables(learner: MaxQLearner) -> None:
    """Taxi 0: asking pays (Q(Root, Com) = 3 > Q(Root, NotCom) = 1); told the other taxi
    waits, it waits one step; told the other one gets B, it gets G; not asking, it gets B.
    Taxi 1 never asks and gets B. (External and internal completions alike: the internal ones
    choose, the external ones are the values parents read.)"""
    for kind in ("C", "C_int"):
        root, com, notcom = (learner.heads[n][kind] for n in ("Root", "Com", "NotCom"))
        com = com.view(2, -1, len(U1), len(U1))  # [taxi, state, other's U_1 code, child]
        with torch.no_grad():
            com[0, :, CODE["Wait"], CODE["Wait"]] = 3.0
            com[0, :, CODE["GetB"], CODE["GetG"]] = 3.0
            notcom[0, :, CODE["GetB"]] = 1.0
            root[1, :, 1] = 10.0  # taxi 1: NotCom
            notcom[1, :, CODE["GetB"]] = 1.0


@pytest.mark.parametrize("cost, asks, second", [(0.0, True, "GetG"), (5.0, False, "GetB")])
def test_communication_changes_the_joint_choice_unless_it_costs_too_much(cost, asks, second):
    env = BusyGAndB()
    agent, learner = _agent(cost)
    _hand_set_tables(learner)
    g = agent.graph
    action = agent.start(env.reset())
    first = g.names[int(g.inst_node[agent.executor.stack.inst[0, 2]])]
    assert first == ("Wait" if asks else "GetB")
    assert bool(agent.messages["asked"][0, 0]) is asks
    assert not bool(agent.messages["asked"][0, 1])  # taxi 1 never asks
    if asks:  # at the start taxi 1 had no task yet: told "Wait" (Cooperation.idle)
        assert agent.messages["told"][0, 0].tolist() == [CODE["Wait"]]
    action, _ = agent.decide(env.step(action))
    if asks:  # its Wait ended; it asks again and is told taxi 1's GetB
        assert bool(agent.messages["asked"][0, 0])
        assert agent.messages["told"][0, 0].tolist() == [CODE["GetB"]]
    else:
        assert agent.messages["told"][0, 0].tolist() == [-1]
    assert g.names[int(g.inst_node[agent.executor.stack.inst[0, 2]])] == second
    assert agent.communications.tolist() == ([2, 0] if asks else [0, 0])
    assert agent.communication_cost.tolist() == [2 * cost if asks else 0.0, 0.0]


def test_com_cost_is_charged_exactly_once_per_communication():
    # exploring taxis on the real task: every push of Com is one communication, whether Com
    # ends after one step (Wait) or after a whole Get or Put
    env = TwoTaxiEnv([0, 1], 4, mean_interarrival=3.0)
    g = com_graph()
    agent = MultiAgentAgent(
        g,
        MaxQLearner(g, 4),
        EpsilonGreedy(1.0),
        agent_rng([0, 1], 4, 2, "com"),
        4,
        2,
        cooperation=COM_COOPERATION,
        communication=Communication(cost=2.5),
    )
    com = g.index["Com"]
    action = agent.start(env.reset())
    asked = agent.messages["asked"].reshape(-1).long()
    for _ in range(300):
        action = agent.step(env.step(action))
        asked += agent.messages["asked"].reshape(-1).long()
    calls = agent.executor.stats.calls[:, com]  # Com's invocations per table set
    per_set = torch.zeros(4).index_add_(0, agent.executor.learner, asked.float())
    assert torch.equal(per_set, calls)
    assert calls.sum() > 50  # communications happened
    assert torch.equal(agent.communications, asked)
    assert torch.allclose(agent.communication_cost, 2.5 * asked.float())


def test_a_bad_communication_level_is_a_clear_error():
    g = com_graph()
    learner = MaxQLearner(g, 2)
    rng = agent_rng([0], 1, 2, "x")

    def make(cooperation, communication):
        return MultiAgentAgent(
            g, learner, Greedy(), rng, 1, 2, cooperation=cooperation, communication=communication
        )

    with pytest.raises(GraphError, match="not a cooperative subtask"):
        make(COM_COOPERATION, Communication(com="NotCom", not_com="Com"))
    with pytest.raises(GraphError, match="not a subtask"):
        make(COM_COOPERATION, Communication(not_com="Talk"))
    with pytest.raises(ValueError, match="finite and >= 0"):
        make(COM_COOPERATION, Communication(cost=-1.0))
    with pytest.raises(ValueError, match="finite and >= 0"):
        make(COM_COOPERATION, Communication(cost=float("nan")))
    both = cooperative_graph(com_graph(), Cooperation((("Com", "NotCom"),)), 2)
    with pytest.raises(GraphError, match="must not be cooperative"):
        MultiAgentAgent(
            both,
            MaxQLearner(both, 2),
            Greedy(),
            rng,
            1,
            2,
            cooperation=Cooperation((("Com", "NotCom"),)),
            communication=Communication(),
        )


def _two_taxi_trainer(seeds):
    import agents  # noqa: F401
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    opts = RunOptions(seeds=seeds, envs_per_learner=4, progress=False, tensorboard=False)
    return build_trainer(registry.get("two-taxi-earlier"), "com-1", opts)


def test_a_com_population_equals_separate_runs():
    together = _two_taxi_trainer([3, 8])
    for _ in range(120):
        together.train_step()
    for p, seed in enumerate([3, 8]):
        alone = _two_taxi_trainer([seed])
        for _ in range(120):
            alone.train_step()
        for bank in ("C", "C_int", "V"):
            mine = getattr(alone.learner, bank).data
            assert torch.equal(mine, getattr(together.learner, bank).data[2 * p : 2 * p + 2])
    com = together.graph.index["Com"]
    assert together.executor.stats.calls[:, com].sum() > 0  # it communicated: not vacuous


def test_lost_and_late_replies():
    # every reply lost: taxi 0 is told "no task" (Wait, the idle code) and keeps waiting
    env = BusyGAndB()
    agent, learner = _agent(0.0, loss=1.0)
    _hand_set_tables(learner)
    action = agent.start(env.reset())
    action, _ = agent.decide(env.step(action))
    assert agent.messages["told"][0, 0].tolist() == [CODE["Wait"]]
    g = agent.graph
    assert g.names[int(g.inst_node[agent.executor.stack.inst[0, 2]])] == "Wait"
    # replies two steps late: taxi 1 chose GetB at the start (step 0); taxi 0, waiting and
    # asking at every step, is told "no task" at steps 1 and 2 and GetB from step 3 on
    agent, learner = _agent(0.0, delay=2)
    _hand_set_tables(learner)
    action = agent.start(env.reset())
    for expected in ("Wait", "Wait", "GetB"):
        action, _ = agent.decide(env.step(action))
        assert agent.messages["told"][0, 0].tolist() == [CODE[expected]]
    with pytest.raises(ValueError, match="loss"):
        _agent_with(Communication(loss=1.5))
    with pytest.raises(ValueError, match="delay"):
        _agent_with(Communication(delay=-1))


def _agent_with(communication):
    g = com_graph()
    return MultiAgentAgent(
        g,
        MaxQLearner(g, 2),
        Greedy(),
        agent_rng([0], 1, 2, "x"),
        1,
        2,
        cooperation=COM_COOPERATION,
        communication=communication,
    )
