"""MAXQ-Q, SMDP Q-learning, RAR, HDR and HAR over multi-step children, against their update
rules written out by hand for one scripted path.

The four-state chain of ``test_q_lambda_and_hh_exact`` (0 -> 1 -> 2 -> 3, rewards -1, -1, +10):
the root runs ``Go2`` from 0 (two primitive steps, ending in 2, non-terminal for the root),
then ``Go3`` from 2 (one step, into the terminal 3). ``Go2`` has a pseudo reward of 3 at its
end, ``Go3`` a shaping reward of 0.5 per step and the root one of 0.25 per step, all
internal. Every step's targets use the values before that step's updates (the learners
evaluate at ``s'`` first), so the references below compute all targets of a step, then apply
them.
"""

import torch

from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import HARLearner, HDRLearner, MaxQLearner, RARLearner, SMDPQLearner
from tests.learners.test_q_lambda_and_hh_exact import chain, run

GAMMA, ALPHA, PSEUDO, SHAPING, ROOT_SHAPING = 0.9, 0.5, 3.0, 0.5, 0.25
STEPS = 3 + 1 + 3  # two episodes and the auto-reset step between them


def per_state_chain(internal_rewards: bool = False):
    """The chain with ``Go2`` abstracting the state (``Go3`` keeps one abstract state)."""
    _, env = chain()
    state = lambda o: o["observation"]  # noqa: E731
    extra1, extra2, extra3 = {}, {}, {}
    if internal_rewards:
        extra1 = {
            "shaping_reward": lambda o, a, o2: torch.full(o["observation"].shape, ROOT_SHAPING)
        }
        extra2 = {"pseudo_reward": lambda o: PSEUDO * (o["observation"] == 2).float()}
        extra3 = {"shaping_reward": lambda o, a, o2: torch.full(o["observation"].shape, SHAPING)}
    nodes = [
        Subtask("Root", ["Go2", "Go3"], n_states=4, abstract=state, **extra1),
        Subtask(
            "Go2",
            ["Right"],
            n_states=4,
            abstract=state,
            terminated=lambda o: o["observation"] == 2,
            **extra2,
        ),
        Subtask("Go3", ["Right"], terminated=lambda o: o["observation"] == 3, **extra3),
        Primitive("Right", 0, 4, state),
    ]
    return TaskGraph("Root", nodes, n_actions=1), env


def step(table, updates):
    """Apply ``{key: target}`` as ``W <- (1 - alpha) W + alpha target``."""
    for key, target in updates.items():
        table[key] = (1 - ALPHA) * table[key] + ALPHA * target


def reference_maxq(episodes=2):
    """Dietterich's MAXQ-Q updates (Table 4 of his paper) on the scripted path."""
    vr = {s: 0.0 for s in range(4)}  # V(Right, s)
    c = {k: 0.0 for k in ("go2@0", "go2@1", "go3", "root@0", "root@2")}  # external C
    ci = dict(c)  # internal C~

    def v_go2(s, table):  # V(Go2, s) reads the child's external V plus the chosen table
        return vr[s] + table[f"go2@{s}"]

    def v_go3(s, table):
        return vr[s] + table["go3"]

    def v_root2(table):  # at 2 only Go3 is available; V uses the external Go3 value
        return v_go3(2, c) + table["root@2"]

    for _ in range(episodes):
        # 0 -> 1: Right and Go2's child end at s' = 1 (not terminal for Go2)
        new_vr = {0: -1.0}
        new_c = {"go2@0": GAMMA * v_go2(1, c)}
        new_ci = {"go2@0": GAMMA * v_go2(1, ci)}
        step(vr, new_vr), step(c, new_c), step(ci, new_ci)
        # 1 -> 2: Go2 ends (pseudo reward inside Go2 only); the root's Go2 took N = 2 steps,
        # during which the root's shaping summed to 0.25 + 0.9 * 0.25
        new_vr = {1: -1.0}
        new_c = {"go2@1": 0.0, "root@0": GAMMA**2 * v_root2(c)}
        root_shaping = ROOT_SHAPING + GAMMA * ROOT_SHAPING
        new_ci = {"go2@1": GAMMA * PSEUDO, "root@0": root_shaping + GAMMA**2 * v_root2(ci)}
        step(vr, new_vr), step(c, new_c), step(ci, new_ci)
        # 2 -> 3: the episode ends; Go3 earned one shaping reward (internal)
        step(vr, {2: 10.0}), step(c, {"go3": 0.0, "root@2": 0.0})
        step(ci, {"go3": SHAPING, "root@2": ROOT_SHAPING})
    return vr, c, ci


def test_maxq_external_and_internal_completions_follow_dietterichs_rules():
    graph, env = per_state_chain(internal_rewards=True)
    learner = MaxQLearner(graph, 1, alpha=ALPHA, gamma=GAMMA)
    run(graph, env, learner, STEPS, gamma=GAMMA)
    vr, c, ci = reference_maxq()
    h = learner.heads
    got = {
        "go2@0": (h["Go2"]["C"][0, 0, 0], h["Go2"]["C_int"][0, 0, 0]),
        "go2@1": (h["Go2"]["C"][0, 1, 0], h["Go2"]["C_int"][0, 1, 0]),
        "go3": (h["Go3"]["C"][0, 0, 0], h["Go3"]["C_int"][0, 0, 0]),
        "root@0": (h["Root"]["C"][0, 0, 0], h["Root"]["C_int"][0, 0, 0]),
        "root@2": (h["Root"]["C"][0, 2, 1], h["Root"]["C_int"][0, 2, 1]),
    }
    for key, (external, internal) in got.items():
        assert abs(float(external) - c[key]) < 1e-5, (key, float(external), c[key])
        assert abs(float(internal) - ci[key]) < 1e-5, (key, float(internal), ci[key])
    for s in range(3):
        assert abs(float(h["Right"]["V"][0, s, 0]) - vr[s]) < 1e-5
    # spot checks by hand: the internal pseudo reward stays out of the external table, and the
    # root's two-step child is discounted by gamma^2 (0.81), not gamma
    assert c["go2@1"] == 0.0 and abs(ci["go2@1"] - 0.75 * 0.9 * 3.0) < 1e-12
    assert abs(c["root@0"] - 0.5 * 0.81 * 5.0) < 1e-12  # episode 2: V(Root, 2) = V(Right, 2)


def test_smdp_q_discounts_the_option_reward_and_its_continuation_by_gamma_to_the_n():
    graph, env = per_state_chain()
    learner = SMDPQLearner(graph, 1, alpha=ALPHA, gamma=GAMMA)
    run(graph, env, learner, STEPS, gamma=GAMMA)
    q = learner.heads["Root"]["Q"][0]
    # episode 1: Q(2, Go3) <- 0.5 * 10 = 5; Q(0, Go2) <- 0.5 * (-1 + 0.9 * -1) = -0.95
    # episode 2: Q(0, Go2) <- -0.95 + 0.5 * (-1.9 + 0.81 * 5 + 0.95) = 0.6; Q(2, Go3) = 7.5
    torch.testing.assert_close(q[0], torch.tensor([0.6, 0.0]))
    torch.testing.assert_close(q[2], torch.tensor([0.0, 7.5]))


def test_rar_bootstraps_from_the_subtask_at_s_prime_and_charges_gain_differences():
    graph, env = per_state_chain()
    learner = RARLearner(graph, 1, alpha=ALPHA)
    run(graph, env, learner, STEPS)
    h, idx = learner.heads, graph.index
    # gains (added after each step's updates): Go2 sees 2 x 2 steps of -1, Go3 2 x +10 in one
    # step, the root 2 x (-2 in 2 steps) and 2 x (+10 in 1 step)
    gains = learner.gain[0][[idx["Go2"], idx["Go3"], idx["Root"]]]
    torch.testing.assert_close(gains, torch.tensor([-1.0, 10.0, 16 / 6]))
    # target: H(i, s') - (g_i - g_a) t, H = 0 at a terminal s'; by step (g before the step):
    #  1: C(Go2, 0) <- .5 * (0 - 0) = 0                     (g_Go2 = 0)
    #  2: C(Go2, 1) <- .5 * (0 + 1) = .5                     (terminal, g_Go2 = -1)
    #     C(Root, 0, Go2) <- .5 * (H(Root, 2) = 0 - (0 + 1) * 2) = -1
    #  3: C(Root, 2, Go3) <- .5 * (0 - (-1 - 0)) = .5;  C(Go3) <- .5 * (0 - 0) = 0
    #  5: C(Go2, 0) <- .5 * (H(Go2, 1) = -.5 + .5 = 0, + 1) = .5
    #  6: C(Go2, 1) <- .5 + .5 * (1 - .5) = .75
    #     H(Root, 2) = V(Right, 2) + C(Go3) + C(Root, 2, Go3) = 5 + 0 + .5 = 5.5
    #     C(Root, 0, Go2) <- -1 + .5 * (5.5 - (8/3 + 1) * 2 + 1) = -1.41667
    #  7: C(Root, 2, Go3) <- .5 + .5 * (0 - (6/5 - 10) - .5) = 4.65 (g_Root = 6 / 5)
    #     C(Go3) <- .5 * (0 - (10 - 0)) = -5
    expected = {
        ("Go2", 0, 0): 0.5,
        ("Go2", 1, 0): 0.75,
        ("Root", 0, 0): -1 + 0.5 * (5.5 - (8 / 3 + 1) * 2 + 1),
        ("Root", 2, 1): 4.65,
        ("Go3", 0, 0): -5.0,
    }
    for (name, s, a), value in expected.items():
        got = float(h[name]["C"][0, s, a])
        assert abs(got - value) < 1e-5, (name, s, a, got, value)


def three_part_tables(learner):
    h = learner.heads
    return {
        "V2": h["Root/Go2/Right"]["V"][0, :, 0],
        "V3": h["Root/Go3/Right"]["V"][0, :, 0],
        "C2": h["Root/Go2"]["C"][0, :, 0],
        "CE2": h["Root/Go2"]["CE"][0, :, 0],
        "C_root": h["Root"]["C"][0],
        "CE_root": h["Root"]["CE"][0],
    }


def test_hdr_discounts_by_gamma_to_the_t_and_hands_ce_over_to_the_parents_w():
    graph, env = per_state_chain()
    learner = HDRLearner(graph, 1, alpha=ALPHA, gamma=GAMMA)
    run(graph, env, learner, STEPS, gamma=GAMMA)
    t = three_part_tables(learner)
    # episode 1 leaves V(Right, .) = -0.5, -0.5 (Go2) and 5 (Go3 at 2), every C and CE 0;
    # episode 2:
    #   C(Go2, 0, Right)  <- .5 * .9 * V(Go2, 1) = .5 * .9 * -.5 = -.225
    #   CE(Go2, 1, Right) <- .5 * .9 * W(Root, 2), W(Root, 2) = V(Go3, 2) + C + CE = 5
    #   C(Root, 0, Go2)   <- .5 * .9^2 * V(Root, 2) = .5 * .81 * 5 = 2.025 (two steps)
    torch.testing.assert_close(t["V2"][:2], torch.tensor([-0.75, -0.75]))
    assert abs(float(t["V3"][2]) - 7.5) < 1e-6
    assert abs(float(t["C2"][0]) + 0.225) < 1e-6
    assert abs(float(t["CE2"][1]) - 2.25) < 1e-6
    assert abs(float(t["C_root"][0, 0]) - 2.025) < 1e-6
    assert float(t["CE_root"][0, 0]) == 0.0 and float(t["CE2"][0]) == 0.0


def test_har_primitives_learn_average_adjusted_rewards_with_the_gain_of_greedy_steps():
    graph, env = per_state_chain()
    learner = HARLearner(graph, 1, alpha=ALPHA)
    run(graph, env, learner, STEPS)
    t = three_part_tables(learner)
    # g after each step (every step greedy): -1, -1, 8/3 | 7/4, 6/5, 16/6; each step's
    # V(Right, x) <- V + .5 (r - g t - V) uses the gain before the step:
    #   V(Right@Go2, 0): -.5, then -.5 + .5 (-1 - 8/3 + .5) = -2.0833
    #   V(Right@Go2, 1): 0 (-1 - (-1)), then .5 (-1 - 7/4) = -1.375
    #   V(Right@Go3, 2): 5.5, then 5.5 + .5 (10 - 6/5 - 5.5) = 7.15
    # undiscounted completions: CE(Go2, 1) <- .5 W(Root, 2) = .5 * 5.5; C(Root, 0, Go2) the same
    assert abs(float(learner.gain[0]) - 16 / 6) < 1e-6
    torch.testing.assert_close(t["V2"][:2], torch.tensor([-0.5 + 0.5 * (-1 - 8 / 3 + 0.5), -1.375]))
    assert abs(float(t["V3"][2]) - 7.15) < 1e-5
    assert abs(float(t["CE2"][1]) - 2.75) < 1e-5
    assert abs(float(t["C_root"][0, 0]) - 2.75) < 1e-5
