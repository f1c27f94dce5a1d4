import pytest
import torch

from envs.trash import (
    CANS,
    DUMP,
    EAST,
    MOVES,
    N_ACTIONS,
    NORTH,
    PICK,
    PUT,
    SOUTH,
    WAIT,
    WEST,
    TrashEnv,
    decode,
    encode,
    exact_model,
    n_joint_states,
)
from hrl_torch.analysis import markov_chain_gain

torch.set_num_threads(1)


def cell(row, col):
    return row * 4 + col


def place(env, location, carrying=(False, False), cans=(True, True)):
    """Put the single row of ``env`` in a given state."""
    env.location = torch.tensor([location])
    env.carrying = torch.tensor([carrying])
    env.cans = torch.tensor([cans])


def step(env, *actions):
    return env.step(torch.tensor([actions]))


@pytest.fixture(scope="module")
def model():
    return exact_model(2, 0.1)


def test_layout_moves_and_walls():
    assert CANS == (cell(0, 0), cell(0, 3)) and DUMP == cell(2, 2)
    expected = {
        (cell(0, 0), SOUTH): cell(1, 0),  # T1's door
        (cell(0, 0), EAST): cell(0, 1),
        (cell(0, 0), WEST): cell(0, 0),  # outer wall
        (cell(0, 1), EAST): cell(0, 1),  # wall between the rooms
        (cell(0, 1), SOUTH): cell(0, 1),
        (cell(0, 3), SOUTH): cell(1, 3),  # T2's door
        (cell(1, 1), SOUTH): cell(1, 1),
        (cell(1, 2), SOUTH): DUMP,  # the dump room's door
        (DUMP, NORTH): cell(1, 2),
        (DUMP, WEST): cell(2, 1),
        (cell(2, 3), NORTH): cell(2, 3),
    }
    for (where, action), to in expected.items():
        assert int(MOVES[where, action]) == to, (where, action)
    assert (MOVES[:, PICK:] == torch.arange(12)[:, None]).all()  # pick, put, wait stay
    # shortest paths: T1 -> Dump 4 moves, T2 -> Dump 3
    reach, frontier = {DUMP: 0}, [DUMP]
    while frontier:
        nxt = []
        for c in frontier:
            for a in range(4):
                d = int(MOVES[c, a])
                if d not in reach:
                    reach[d] = reach[c] + 1
                    nxt.append(d)
        frontier = nxt
    assert len(reach) == 12 and reach[CANS[0]] == 4 and reach[CANS[1]] == 3


def test_pick_put_and_rewards_by_hand():
    env = TrashEnv([0], 1, refill_prob=0.0)
    env.reset()
    place(env, [CANS[0], CANS[0]])
    td = step(env, PICK, PICK)  # both pick at T1: robot 0 gets the load
    assert td["agents", "carrying"].tolist() == [[1, 0]]
    assert td["t1_full"].item() == 0 and td["t2_full"].item() == 1 and td["cans"].item() == 2
    assert td["reward"].item() == -2.0
    assert td["agents", "reward"].tolist() == [[-2.0, -2.0]]  # the team reward, per agent
    td = step(env, WAIT, PICK)  # nothing left at T1; wait costs nothing
    assert td["agents", "carrying"].tolist() == [[1, 0]] and td["reward"].item() == -1.0
    for action in (SOUTH, EAST, EAST, SOUTH):
        td = step(env, action, WAIT)
    assert td["agents", "location"].tolist() == [[DUMP, CANS[0]]]
    td = step(env, PUT, PUT)  # robot 1 carries nothing: its put does nothing
    assert td["reward"].item() == 20.0 - 2.0
    assert td["agents", "dumped"].tolist() == [[1, 0]] and td["n_dumped"].item() == 1
    assert td["agents", "carrying"].tolist() == [[0, 0]]
    assert td["agents", "last_action"].tolist() == [[PUT, PUT]]
    td = step(env, PUT, WAIT)
    assert td["reward"].item() == -1.0 and td["n_dumped"].item() == 0
    # a loaded robot's put away from the Dump and a pick at a can while loaded do nothing
    place(env, [CANS[1], DUMP], carrying=[True, False], cans=[False, True])
    td = step(env, PICK, PUT)
    assert td["agents", "carrying"].tolist() == [[1, 0]] and td["t2_full"].item() == 1


def test_refill_process():
    env = TrashEnv([0], 1, refill_prob=1.0)
    env.reset()
    place(env, [CANS[0], CANS[1]], cans=[True, False])
    td = step(env, PICK, WAIT)  # T1 emptied this step stays empty; empty T2 refills
    assert (td["t1_full"].item(), td["t2_full"].item()) == (0, 1)
    td = step(env, WAIT, WAIT)
    assert (td["t1_full"].item(), td["t2_full"].item()) == (1, 1)
    env = TrashEnv([0], 1, refill_prob=0.0)
    env.reset()
    place(env, [CANS[0], CANS[1]])
    step(env, PICK, PICK)
    for _ in range(20):
        td = step(env, WAIT, WAIT)
    assert td["cans"].item() == 0


def test_start_state_and_observation_fields():
    env = TrashEnv([0], 4000)
    td = env.reset()
    assert (td["cans"] == 3).all() and (td["agents", "carrying"] == 0).all()
    assert (td["agents", "last_action"] == N_ACTIONS).all()
    counts = torch.bincount(td["agents", "location"].flatten(), minlength=12).float()
    assert counts.min() > 0.8 * counts.mean()
    fields = decode(td["observation"], 2)
    assert torch.equal(fields["location"], td["agents", "location"])
    own = td["agents", "own_state"]
    assert torch.equal(own % 4, td["cans"][:, None].expand_as(own))
    assert torch.equal(own // 8, td["agents", "location"])
    assert torch.equal(td["agents", "row"] * 4 + td["agents", "col"], td["agents", "location"])


def test_encode_decode_round_trip():
    for n in (1, 2, 3):
        s = torch.arange(n_joint_states(n))
        f = decode(s, n)
        assert f["location"].shape == (len(s), n) and f["cans"].shape == (len(s), 2)
        assert torch.equal(encode(f["location"], f["carrying"], f["cans"]), s)


def run(env, actions):
    env.reset()
    return [env.step(a) for a in actions]


def test_population_equals_separate_runs():
    g = torch.Generator().manual_seed(0)
    actions = torch.randint(0, N_ACTIONS, (60, 12, 2), generator=g)
    big = run(TrashEnv([3, 5, 7], 4, max_episode_steps=25), actions)
    small = run(TrashEnv([5], 4, max_episode_steps=25), actions[:, 4:8])
    for a, b in zip(big, small, strict=True):
        assert (a[4:8] == b).all()


def test_state_dict_round_trip_continues_identically():
    g = torch.Generator().manual_seed(1)
    actions = torch.randint(0, N_ACTIONS, (40, 6, 2), generator=g)
    env = TrashEnv([0, 1], 3, max_episode_steps=15)
    env.reset()
    for a in actions[:20]:
        env.step(a)
    state = env.state_dict()
    first = [env.step(a) for a in actions[20:]]
    other = TrashEnv([0, 1], 3, max_episode_steps=15)
    other.load_state_dict(state)
    second = [other.step(a) for a in actions[20:]]
    for a, b in zip(first, second, strict=True):
        assert (a == b).all()


def test_every_sampled_transition_is_in_the_exact_model(model):
    env = TrashEnv([0], 2048)
    td = env.reset()
    g = torch.Generator().manual_seed(2)
    for _ in range(30):
        action = torch.randint(0, N_ACTIONS, (2048, 2), generator=g)
        before = td["observation"]
        td = env.step(action)
        p = model.probability(before, model.joint_action(action), td["observation"])
        assert (p > 0).all()
        reward = model.reward[before, model.joint_action(action)]
        assert torch.equal(reward.float(), td["reward"])
        assert torch.equal(model.dumped[before, model.joint_action(action)], td["n_dumped"])


def test_outcome_frequencies_match_the_model(model):
    n = 20_000
    env = TrashEnv([0], n)
    env.reset()
    env.location = torch.tensor([[cell(1, 0), CANS[1]]]).repeat(n, 1)
    env.carrying = torch.zeros(n, 2, dtype=torch.bool)
    env.cans = torch.zeros(n, 2, dtype=torch.bool)
    before = int(encode(env.location[0], env.carrying[0], env.cans[0]))
    action = torch.tensor([NORTH, PICK])
    td = env.step(action.repeat(n, 1))
    joint = model.joint_action(action)
    outcomes = model.next_state[before, joint]
    assert len(set(outcomes.tolist())) == 4
    for s_next, p in zip(outcomes.tolist(), model.prob.tolist(), strict=True):
        freq = (td["observation"] == s_next).double().mean().item()
        assert abs(freq - p) < 4.5 * (p * (1 - p) / n) ** 0.5 + 1e-9, (s_next, freq, p)


def dp_policy(model) -> torch.Tensor:
    """Discounted value iteration over the joint model: a purposeful joint policy ``[S]``."""
    v = torch.zeros(model.n_states, dtype=torch.float64)
    for _ in range(200):
        q = model.reward + 0.95 * (v[model.next_state] * model.prob).sum(-1)
        v = q.max(1).values
    return q.argmax(1)


def test_env_under_a_dp_policy_earns_the_exact_expected_reward(model):
    policy = dp_policy(model)
    assert torch.equal(TrashEnv([0], 1, refill_prob=0.1).exact_model().next_state, model.next_state)
    assert (model.dumped[torch.arange(model.n_states), policy] > 0).any()
    p, r = model.chain(policy)
    assert torch.allclose(p.sum(1), torch.ones(model.n_states, dtype=torch.float64))
    horizon, n = 40, 4096
    dist, expected = model.start_distribution(), []
    for _ in range(horizon):
        expected.append(float(dist @ r))
        dist = dist @ p
    env = TrashEnv([0, 1], n // 2)
    td = env.reset()
    sampled = []
    for _ in range(horizon):
        td = env.step(model.robot_actions(policy[td["observation"]]))
        sampled.append(td["reward"].double().mean().item())
    mean_expected, mean_sampled = sum(expected) / horizon, sum(sampled) / horizon
    assert mean_expected > 0.5  # the DP policy collects trash
    assert abs(mean_sampled - mean_expected) < 0.05, (mean_sampled, mean_expected)


@pytest.mark.slow  # (the 2,304-state chain's closure and the 440 dense steps: 4/5 of the old
# test's time; the fast suite runs the gain of this model's chain under another joint policy in
# tests/test_multiagent.py and of hand-made chains in tests/test_analysis.py)
def test_the_dp_policy_s_chain_has_its_long_run_reward_per_step_as_gain(model):
    # the chain feeds hrl_torch.analysis: its gain is the long-run reward per step
    p, r = model.chain(dp_policy(model))
    gain = markov_chain_gain(p, r).gain
    dist = model.start_distribution()
    for _ in range(240):
        dist = dist @ p
    late = []
    for _ in range(200):
        late.append(float(dist @ r))
        dist = dist @ p
    assert torch.allclose(gain, gain[0]) and abs(gain[0].item() - sum(late) / 200) < 1e-3


def test_bad_arguments_are_clear_errors():
    with pytest.raises(ValueError, match="refill_prob"):
        TrashEnv([0], 1, refill_prob=1.5)
    env = TrashEnv([0], 2)
    env.reset()
    with pytest.raises(ValueError, match=r"action 7 of agent 1 outside the action space"):
        env.step(torch.tensor([[0, 0], [0, 7]]))
    with pytest.raises(ValueError, match="exact_model with 3 robots"):
        exact_model(3)
