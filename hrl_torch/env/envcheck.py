"""``check_env``: does a batched env keep the contract the executor relies on?

Run it on your own env before training (the trainer of ``run_experiment`` runs it once, on a
small env of the domain): each broken rule is one line naming the field, what was expected
and what was found, so a wrong shape or dtype does not surface deep inside a learner.

The contract (``hrl_torch.env.batched``): ``reset()`` and ``step(action)`` return a TensorDict
``[B]`` on ``env.device`` with ``reward`` / ``duration`` float ``[B]`` (finite, durations
``>= 0``), ``terminated`` / ``truncated`` / ``is_init`` bool ``[B]``, and the declared
observation fields (``observation_sizes``: integer ``[B]`` in ``[0, n)``;
``observation_bounds``: float ``[B, *shape]``, finite). Next-step auto-reset: a row that ended
at step ``t`` is reset at ``t + 1`` (``is_init``, reward 0, neither flag set); ``reset()`` marks
every row ``is_init``. A checkpointable env replays the same outputs from the same
``state_dict``; with ``make_env`` a learner's rows in a population equal the same seed alone.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDict

from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError

FLOAT_FIELDS = ("reward", "duration")
FLAG_FIELDS = ("terminated", "truncated", "is_init")


class EnvContractError(ValueError):
    """An env that breaks the batched-env contract; ``failures`` lists every broken rule."""

    def __init__(self, failures: Sequence[str]) -> None:
        self.failures = list(failures)
        lines = "\n".join(f"  - {f}" for f in self.failures)
        super().__init__(f"the env breaks {len(self.failures)} rule(s) of the contract:\n{lines}")


def check_env(
    env,
    graph: TaskGraph | None = None,
    make_env: Callable[[Sequence[int], int], object] | None = None,
    steps: int = 64,
    torchrl: bool = False,
    gymnasium: bool = False,
) -> None:
    """Step ``env`` with random actions and check every output; raise ``EnvContractError``.

    Args:
        env: a batched env (``BatchedEnv`` or anything with its interface). It is stepped;
            a checkpointable env is put back in its state afterwards.
        graph: also check that every node's abstraction gives integer states in range.
        make_env: ``(seeds, envs_per_learner) -> env``: also check that learner 1 of a
            two-seed population sees what the same seed sees alone (a row's random stream
            must not depend on the other rows).
        steps: random steps to take.
        torchrl: also run TorchRL's ``check_env_specs`` on the env's TorchRL wrapper
            (``TorchRLEnv``, or ``MultiAgentTorchRLEnv`` for a multi-agent env).
        gymnasium: also run gymnasium's ``check_env`` on one row of ``make_env`` as a
            ``gymnasium.Env`` (``hrl_torch.env.adapters.BatchedToGymnasium``; needs ``make_env``).
    """
    failures: list[str] = []
    state = env.state_dict()
    try:
        outputs, actions = _rollout(env, steps, failures)
        for t, td in enumerate(outputs):
            _check_output(env, td, f"{'reset' if t == 0 else f'step {t}'}", failures)
            if graph is not None:
                _check_abstractions(graph, td, t, failures)
        _check_auto_reset(outputs, failures)
        if state:  # a checkpointable env replays the same outputs from the same state
            env.load_state_dict(state)
            again, _ = _rollout(env, steps, [], actions=actions)
            _compare(outputs, again, "replayed from the same state_dict", failures)
        if make_env is not None:
            _check_population(make_env, steps, failures)
        if torchrl:
            _check_torchrl(env, failures)
        if gymnasium:
            _check_gymnasium(make_env, failures)
    finally:
        if state:
            env.load_state_dict(state)
    if failures:
        raise EnvContractError(_first_of_each(failures))


def _first_of_each(failures: list[str]) -> list[str]:
    """The first failure of each rule (the same rule broken at later steps is not repeated)."""
    seen, out = set(), []
    for f in failures:
        rule = f.split(": ", 1)[-1].split(" (env row")[0]
        if rule not in seen:
            seen.add(rule)
            out.append(f)
    return out


def _random_action(env, gen: torch.Generator) -> torch.Tensor:
    b = env.batch_size
    if env.n_agents is not None:
        shape = (b, env.n_agents)
        return torch.randint(env.n_actions, shape, generator=gen).to(env.device)
    if env.n_actions is not None:
        return torch.randint(env.n_actions, (b,), generator=gen).to(env.device)
    low, high = (torch.tensor(x, dtype=torch.float32) for x in env.action_bounds)
    u = torch.rand((b, *low.shape), generator=gen)
    return (low + u * (high - low)).to(env.device)


def _rollout(env, steps: int, failures: list[str], actions=None):
    """``reset`` then ``steps`` steps (random ``actions`` unless given): outputs, actions."""
    gen = torch.Generator().manual_seed(0)
    actions = list(actions) if actions is not None else []
    outputs = []
    try:
        outputs.append(env.reset())
        for t in range(steps):
            if t == len(actions):
                actions.append(_random_action(env, gen))
            outputs.append(env.step(actions[t]))
    except Exception as err:  # a crash is a finding too; keep what was seen
        failures.append(f"step {len(outputs)} raised {type(err).__name__}: {err}")
    return outputs, actions


def _check_output(env, td, where: str, failures: list[str]) -> None:
    b = env.batch_size
    if not isinstance(td, TensorDict):
        failures.append(f"{where}: expected a TensorDict, found {type(td).__name__}")
        return
    if tuple(td.batch_size) != (b,):
        failures.append(f"{where}: batch_size expected [{b}], found {list(td.batch_size)}")
        return
    if td.device != env.device:
        failures.append(f"{where}: device expected {env.device}, found {td.device}")
    for key in FLOAT_FIELDS:
        _field(td, key, where, failures, shape=(b,), floating=True)
    for key in FLAG_FIELDS:
        _field(td, key, where, failures, shape=(b,), dtype=torch.bool)
    for key, n in env.observation_sizes.items():
        value = _field(td, key, where, failures, shape=(b,), floating=False)
        if value is not None and bool(((value < 0) | (value >= n)).any()):
            row = int(((value < 0) | (value >= n)).nonzero()[0])
            failures.append(
                f"{where}: field {key!r} expected values in [0, {n}), found {int(value[row])} "
                f"(env row {row})"
            )
    for key, (low, _) in env.observation_bounds.items():
        shape = (b, *torch.tensor(low).shape)
        value = _field(td, key, where, failures, shape=shape, floating=True)
        if value is not None and not bool(value.isfinite().all()):
            failures.append(f"{where}: field {key!r} expected finite values, found non-finite")
    reward, duration = td.get("reward", None), td.get("duration", None)
    if reward is not None and duration is not None and reward.shape == duration.shape:
        bad = ~reward.isfinite() | ~duration.isfinite() | (duration < 0)
        if bool(bad.any()):
            row = int(bad.nonzero()[0])
            failures.append(
                f"{where}: reward and duration expected finite (duration >= 0), found "
                f"{float(reward[row])} and {float(duration[row])} (env row {row})"
            )
    flags = [td.get(k, None) for k in FLAG_FIELDS]
    if all(f is not None and f.dtype == torch.bool and f.shape == (b,) for f in flags):
        term, trunc, init = flags
        if where == "reset" and not bool(init.all()):
            failures.append("reset: field 'is_init' expected True in every row")
        if bool((init & (term | trunc)).any()):
            failures.append(f"{where}: a row is_init and terminated/truncated at once")


def _field(td, key, where, failures, shape, dtype=None, floating=None):
    """The field if it exists with the expected shape and dtype (else a failure, ``None``)."""
    if key not in td.keys():
        failures.append(f"{where}: field {key!r} missing")
        return None
    value = td[key]
    found = f"{list(value.shape)} {value.dtype}"
    if tuple(value.shape) != tuple(shape):
        failures.append(f"{where}: field {key!r} expected shape {list(shape)}, found {found}")
        return None
    if dtype is not None and value.dtype != dtype:
        failures.append(f"{where}: field {key!r} expected dtype {dtype}, found {found}")
        return None
    if floating is not None and value.is_floating_point() != floating:
        kind = "a float dtype" if floating else "an integer dtype"
        failures.append(f"{where}: field {key!r} expected {kind}, found {found}")
        return None
    return value


def _check_auto_reset(outputs: list, failures: list[str]) -> None:
    """A row that ended at ``t`` is reset at ``t + 1`` with reward 0; no other row is."""
    for t in range(1, len(outputs) - 1):
        now, then = outputs[t], outputs[t + 1]
        try:
            ended = now["terminated"] | now["truncated"]
            reset, reward = then["is_init"], then["reward"]
        except (KeyError, RuntimeError, TypeError):
            return  # already reported
        if not torch.equal(reset, ended):
            row = int((reset != ended).nonzero()[0])
            failures.append(
                f"step {t + 1}: field 'is_init' expected {bool(ended[row])} (the row "
                f"{'ended' if bool(ended[row]) else 'did not end'} at step {t}), found "
                f"{bool(reset[row])} (env row {row})"
            )
            return
        if bool((reward[reset] != 0).any()):
            failures.append(f"step {t + 1}: a reset row expected reward 0, found non-zero")
            return


def _compare(first: list, second: list, how: str, failures: list[str], rows=None) -> None:
    for t, (a, b) in enumerate(zip(first, second, strict=False)):
        for key in a.keys(include_nested=True, leaves_only=True):
            if key not in b.keys(include_nested=True, leaves_only=True):
                continue
            x, y = a[key], b[key]
            if rows is not None:
                x = x[rows]
            if x.shape != y.shape or not torch.equal(x, y):
                failures.append(f"step {t}: field {key!r} differs when {how}")
                return


def _check_population(make_env, steps: int, failures: list[str]) -> None:
    """Learner 1 of seeds ``[3, 7]`` sees what seed 7 sees alone (same actions)."""
    pair, alone = make_env([3, 7], 2), make_env([7], 2)
    gen = torch.Generator().manual_seed(1)
    acts = [_random_action(pair, gen) for _ in range(steps)]
    crashed: list[str] = []  # a population of two that crashes is a finding too
    first, _ = _rollout(pair, steps, crashed, actions=acts)
    second, _ = _rollout(alone, steps, crashed, actions=[a[2:] for a in acts])
    failures.extend(f"in a population of seeds [3, 7] / seed 7 alone: {c}" for c in crashed)
    _compare(first, second, "the same seed runs in a population", failures, rows=slice(2, 4))


def _check_abstractions(graph: TaskGraph, td, t: int, failures: list[str]) -> None:
    try:
        graph.context(td)
    except GraphError as err:
        failures.append(f"{'reset' if t == 0 else f'step {t}'}: {err}")


def _check_torchrl(env, failures: list[str]) -> None:
    from torchrl.envs.utils import check_env_specs

    from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv
    from hrl_torch.env.torchrl_env import TorchRLEnv
    from hrl_torch.env.torchrl_multiagent import MultiAgentTorchRLEnv

    wrapper = MultiAgentTorchRLEnv if isinstance(env, MultiAgentBatchedEnv) else TorchRLEnv
    try:
        check_env_specs(wrapper(env))
    except Exception as err:
        failures.append(f"TorchRL check_env_specs: {str(err).splitlines()[0]}")


def _check_gymnasium(make_env, failures: list[str]) -> None:
    import gymnasium.utils.env_checker

    from hrl_torch.env.adapters import BatchedToGymnasium

    if make_env is None:
        raise ValueError("check_env(gymnasium=True) needs make_env")
    try:
        gymnasium.utils.env_checker.check_env(BatchedToGymnasium(make_env), skip_render_check=True)
    except Exception as err:
        failures.append(f"gymnasium check_env: {str(err).splitlines()[0]}")
