"""A grid of configurations x seeds as one population equals its separate runs, table for table.

Also: a per-learner tensor of equal values gives the number's tables bit for bit, what cannot
be per learner is refused, and ``hrl-torch sweep --population`` writes the sweep's table.
"""

import argparse
import csv
import dataclasses
import json

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from agents.taxi import flat_graph, taxi_hierarchy
from envs.taxi import TaxiEnv
from hrl_torch.common.config import Make, same
from hrl_torch.common.sync_count import count_train_step
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.learners import (
    HPGRLLearner,
    MaxQLearner,
    QLambdaLearner,
    RVIQLearner,
    SMDPQLearner,
)
from hrl_torch.learners.pg import PGConfig
from hrl_torch.modules.exploration import Boltzmann, EpsilonGreedy
from hrl_torch.modules.schedules import Linear
from hrl_torch.modules.tables import TableBank, TableSet
from hrl_torch.runs import registry
from hrl_torch.runs.cli_parser import add_sweep_parser
from hrl_torch.runs.domain import with_overrides
from hrl_torch.runs.experiment import RunOptions, build_trainer, continue_options
from hrl_torch.runs.population_grid import (
    population_values,
    run_population_command,
    train_grid,
    with_values,
)
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer
from tests.test_any_device import _tensors

SEEDS = [0, 1, 2, 3, 4]
#: shared by every configuration: a small budget (600 batched steps of 2 envs per seed)
FIXED = {"steps": 1200, "envs_per_learner": 2, "eval_episodes": 3, "eval_every": 0}


def tables(trainer) -> dict[str, torch.Tensor]:
    """Every table bank's ``[P, total]`` tables."""
    banks = {n: m for n, m in trainer.learner.named_modules() if isinstance(m, TableBank)}
    return {n: m.data.clone() for n, m in banks.items()}


def test_a_4x2_grid_of_5_seeds_as_one_population_equals_the_8_separate_runs():
    taxi = registry.get("taxi")
    grid = [
        {**FIXED, "learner.alpha": a, "exploration.epsilon.end": e}
        for a in (0.1, 0.137, 0.3, 0.5)  # 1 - 0.137 in float32: not 1 - float32(0.137)
        for e in (0.05, 0.3)
    ]
    together, result = train_grid(taxi, "maxq-q", grid, SEEDS)
    pop = tables(together)
    s = len(SEEDS)
    for c, config in enumerate(grid):
        alone, alone_result = train_grid(taxi, "maxq-q", [config], SEEDS)  # numbers, not tensors
        for name, value in tables(alone).items():
            assert torch.equal(value, pop[name][c * s : (c + 1) * s]), (config, name)
        assert alone_result.final_eval == result.final_eval[c * s : (c + 1) * s], config
    # the values reached the learners: the configurations' tables differ (seed 0 of each)
    first = [pop["C"][c * s] for c in range(len(grid))]
    assert all(not torch.equal(first[0], other) for other in first[1:])


def trainer_with(seeds, alpha, end, learner_cls, graph_fn, envs):
    graph = graph_fn()
    learner = learner_cls(graph, len(seeds), alpha=alpha, gamma=0.95)
    config = TrainConfig(steps=10**9, eval_every=0, eval_episodes=0, progress=False)
    exploration = EpsilonGreedy(Linear(1.0, end, 400 * envs))
    return Trainer(
        TaxiEnv(seeds, envs), graph, learner, exploration, config, None, ExecutorConfig()
    )


@pytest.mark.parametrize("envs", [1, 4])  # 1: the plain update of distinct rows; 4: grouped
@pytest.mark.parametrize(
    "learner_cls,graph_fn",
    [(MaxQLearner, taxi_hierarchy), (SMDPQLearner, flat_graph), (QLambdaLearner, taxi_hierarchy)],
)
def test_a_tensor_of_equal_values_gives_the_numbers_tables(learner_cls, graph_fn, envs):
    seeds = [3, 11, 42]
    # float64, as the numbers are (float32(1 - a) differs from 1 - float32(a) at a = 0.137)
    alpha, end = (torch.full((len(seeds),), x, dtype=torch.float64) for x in (0.137, 0.1))
    numbers = trainer_with(seeds, 0.137, 0.1, learner_cls, graph_fn, envs)
    tensors = trainer_with(seeds, alpha, end, learner_cls, graph_fn, envs)
    numbers.train(steps=600 * envs)
    tensors.train(steps=600 * envs)
    for name, value in tables(numbers).items():
        assert torch.equal(value, tables(tensors)[name]), name
    assert any((t != 0).any() for t in tables(numbers).values())  # trained


@pytest.mark.parametrize(
    "choosers", [(), (3,)]
)  # level by level [B, ...], all at once [B, Ic, ...]
def test_per_learner_exploration_chooses_as_each_learner_s_numbers(choosers):
    gen = torch.Generator().manual_seed(0)
    b, a = 64, 5
    q = torch.randn(b, *choosers, a, generator=gen) * 3
    available = torch.rand(b, *choosers, a, generator=gen) > 0.3
    available[..., 0] = True
    u = torch.rand(b, *choosers, a + 1, generator=gen)
    learner = torch.arange(b) % 4
    ends, temps = [0.05, 0.137, 0.3, 0.9], [0.137, 0.5, 1.3, 2.0]
    per = lambda xs: torch.tensor(xs, dtype=torch.float64)  # noqa: E731
    cases = [
        (
            EpsilonGreedy(Linear(1.0, per(ends), 100)),
            [EpsilonGreedy(Linear(1.0, e, 100)) for e in ends],
        ),
        (Boltzmann(per(temps)), [Boltzmann(t) for t in temps]),
    ]
    for together, alone in cases:
        choice, greedy = together.select(q, available, u, 37, learner)
        for p, own in enumerate(alone):
            rows = learner == p
            mine = own.select(q[rows], available[rows], u[rows], 37)
            assert torch.equal(mine[0], choice[rows]) and torch.equal(mine[1], greedy[rows])
    with pytest.raises(ValueError, match="needs the rows' learners"):
        cases[0][0].select(q, available, u, 37)


def test_a_per_learner_init_fills_each_learner_s_tables_as_its_number():
    n_states, n_cols = torch.tensor([3, 0, 2]), torch.tensor([2, 1, 4])
    inits = [-20.0, 0.1, 7.3]
    per = torch.tensor(inits, dtype=torch.float64)
    bank = TableBank(3, n_states, n_cols, per, pad=4)
    for p, init in enumerate(inits):
        assert torch.equal(bank.data[p], TableBank(1, n_states, n_cols, init).data[0])
    # a set of banks keeps each learner's own initial values
    together = TableSet(C=TableBank(3, n_states, n_cols, per), V=TableBank(3, n_states, n_cols))
    assert torch.equal(together.banks["C"].data, bank.data) and not together.banks["V"].data.any()
    with pytest.raises(ValueError, match="one per learner"):
        TableBank(2, n_states, n_cols, per)
    number, tensor = (RVIQLearner(flat_graph(), 3, init=x) for x in (-2.5, torch.full((3,), -2.5)))
    assert torch.equal(number.q_sum, tensor.q_sum) and torch.equal(number.Q.data, tensor.Q.data)


def test_a_grid_over_init_as_one_population_equals_its_separate_runs():
    taxi = registry.get("taxi")
    fixed = {**FIXED, "steps": 600}
    grid = [{**fixed, "learner.init": i, "learner.alpha": a} for i in (-20, 0) for a in (0.3, 0.5)]
    together, _ = train_grid(taxi, "maxq-q", grid, SEEDS[:2])
    for c, config in enumerate(grid):
        alone, _ = train_grid(taxi, "maxq-q", [config], SEEDS[:2])
        for name, value in tables(alone).items():
            assert torch.equal(value, tables(together)[name][2 * c : 2 * c + 2]), (config, name)


def test_population_values_are_configuration_major_and_shared_values_stay_numbers():
    grid = [{"alpha": a, "gamma": 0.9} for a in (0.1, 0.5)]
    values = population_values(grid, 3)
    assert values["gamma"] == 0.9
    assert values["alpha"].tolist() == [0.1, 0.1, 0.1, 0.5, 0.5, 0.5]
    assert values["alpha"].dtype == torch.float64


def test_what_cannot_differ_within_a_population_is_refused():
    with pytest.raises(ValueError, match="gamma cannot differ within one population"):
        population_values([{"gamma": 0.9}, {"gamma": 1.0}], 2)
    with pytest.raises(ValueError, match="must be a number"):
        population_values([{"alpha": True}, {"alpha": 0.5}], 2)
    with pytest.raises(ValueError, match="one per learner"):
        MaxQLearner(taxi_hierarchy(), 3, alpha=torch.tensor([0.1, 0.2]))
    with pytest.raises(ValueError, match="alpha must be one number"):
        HPGRLLearner(taxi_hierarchy(), 2, PGConfig(alpha=torch.tensor([0.1, 0.2])))
    with pytest.raises(ValueError, match=r"cannot sweep exploration.epsilon.stop: choose .*\.end"):
        with_values(registry.get("taxi").algos["maxq-q"], {"exploration.epsilon.stop": 0.1})


def test_a_population_grid_builds_on_meta_and_a_step_reads_nothing_back():
    taxi = registry.get("taxi")
    grid = [
        {"learner.alpha": a, "exploration.epsilon.end": e} for a, e in ((0.1, 0.01), (0.5, 0.3))
    ]
    spec = with_values(taxi.algos["maxq-q"], population_values(grid, 2))
    domain = dataclasses.replace(taxi, algos={**taxi.algos, "maxq-q": spec})
    for device in ("meta", "cpu"):
        opts = RunOptions(seeds=range(4), envs_per_learner=2, eval_episodes=0, progress=False)
        trainer = build_trainer(domain, "maxq-q", dataclasses.replace(opts, device=device))
        if device == "meta":  # every tensor there, the per-learner values included
            found: list = []
            _tensors(trainer, "trainer", found, set())
            assert [p for p, dev in found if dev.type != "meta"] == []
            assert trainer.learner.alpha.value.device.type == "meta"
            trainer.train_step()
        else:
            assert count_train_step(trainer, 70, stacks=True).total == 0


def sweep_args(*argv):
    parser = argparse.ArgumentParser()
    add_sweep_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["sweep", *argv])


def test_the_command_line_writes_the_sweep_table_and_every_seed(tmp_path, capsys):
    argv = ["taxi", "--algo", "smdp-q", "--population", "--seeds", "2", "--steps", "512"]
    argv += ["--grid", "learner.alpha=0.1,0.5", "--grid", "exploration.epsilon.end=0.05"]
    argv += ["--out", str(tmp_path), "--name", "g"]
    assert run_population_command(sweep_args(*argv)) == 0
    folder = tmp_path / "g"
    assert "| rank | learner.alpha | exploration.epsilon.end |" in capsys.readouterr().out
    assert json.loads((folder / "sweep.json").read_text())["population"] is True
    with open(folder / "sweep.csv") as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["learner.alpha"] for r in rows) == ["0.1", "0.5"]
    with open(folder / "per_seed.csv") as f:
        per_seed = list(csv.DictReader(f))
    assert [(r["learner.alpha"], r["seed"]) for r in per_seed] == [
        ("0.1", "0"),
        ("0.1", "1"),
        ("0.5", "0"),
        ("0.5", "1"),
    ]
    # hparams.json: the shared settings, and per configuration its values as numbers; together
    # exactly a separate run's settings (as its hparams.json writes them)
    hparams = json.loads((folder / "hparams.json").read_text())
    assert hparams["configurations"] == [{"learner.alpha": 0.1}, {"learner.alpha": 0.5}]
    assert hparams["seeds"] == [0, 1] and hparams["train.steps"] == 512
    spec = registry.get("taxi").algos["smdp-q"]
    for config, alpha in zip(hparams["configurations"], (0.1, 0.5), strict=True):
        own = {"learner.alpha": alpha, "exploration.epsilon.end": 0.05}
        alone = with_overrides(spec, own).settings()
        assert {**hparams["settings"], **config} == json.loads(json.dumps(alone, default=str))
    with pytest.raises(ValueError, match="exists"):
        run_population_command(sweep_args(*argv))
    with pytest.raises(ValueError, match="--in-process runs the trials one by one"):
        run_population_command(sweep_args(*argv, "--in-process"))
    with pytest.raises(ValueError, match="--resume is for Ray sweeps"):
        run_population_command(sweep_args(*argv, "--resume"))


def test_settings_holding_tensors_compare_resume_and_write_as_numbers(tmp_path):
    alpha = torch.tensor([0.1, 0.1, 0.5, 0.5], dtype=torch.float64)
    record = Make(MaxQLearner, alpha=alpha, gamma=0.95)
    assert record == Make(MaxQLearner, alpha=alpha.clone(), gamma=0.95)
    assert record != Make(MaxQLearner, alpha=alpha.flip(0), gamma=0.95)
    assert record != Make(MaxQLearner, alpha=alpha.float(), gamma=0.95)  # float32: not the numbers
    assert record != Make(MaxQLearner, alpha=0.1, gamma=0.95)
    assert same(EpsilonGreedy(Linear(1.0, alpha, 10)).epsilon, Linear(1.0, alpha.clone(), 10))
    # the resume check compares the recorded settings with the given ones
    run = {"domain": "taxi", "algo": "maxq-q", "seeds": [0, 1, 2, 3], "settings": {"alpha": alpha}}
    opts = continue_options("c.pt", run, settings={"alpha": alpha.clone()})
    assert torch.equal(opts.settings["alpha"], alpha)
    with pytest.raises(ValueError, match="settings .* differs from the checkpoint's run"):
        continue_options("c.pt", run, settings={"alpha": alpha * 2})
    # a run's hparams.json lists a per-learner value as its numbers
    from hrl_torch.training.runlog import RunLogger

    RunLogger(tmp_path, [0, 1, 2, 3], {"options.settings": {"alpha": alpha}}, tensorboard=False)
    written = json.loads((tmp_path / "hparams.json").read_text())
    assert written["options.settings"] == {"alpha": [0.1, 0.1, 0.5, 0.5]}
