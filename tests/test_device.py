"""The device option end to end, and the collector path from the CLI."""

import json
import warnings

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.runs import registry
from hrl_torch.runs.cli import main
from hrl_torch.runs.experiment import RunOptions, build_trainer


def _tables_after(steps, **options):
    opts = RunOptions(seeds=[0, 1], envs_per_learner=8, progress=False, tensorboard=False)
    for key, value in options.items():
        setattr(opts, key, value)
    trainer = build_trainer(registry.get("taxi"), "maxq-q", opts)
    for _ in range(steps):
        trainer.train_step()
    trainer.close()
    return trainer, {k: v.cpu() for k, v in trainer.learner.state_dict().items()}


def test_every_tensor_of_a_run_lives_on_the_chosen_device():
    trainer, _ = _tables_after(3, device="cpu")
    device = torch.device("cpu")
    assert trainer.env.device == device and trainer.env.rng._row_key.device == device
    assert trainer.executor.stack.inst.device == device
    assert all(b.device == device for b in trainer.learner.buffers())


def test_the_gymnasium_backend_runs_through_the_same_trainer():
    trainer, tables = _tables_after(30, backend="gymnasium")
    assert trainer.env.learner_of_row().device == torch.device("cpu")
    assert any(t.ne(t.flatten()[0]).any() for t in tables.values())  # it learned something


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_learns_the_tables_the_cpu_learns():
    trainer, on_gpu = _tables_after(200, device="cuda")
    assert trainer.executor.stack.inst.is_cuda and trainer.env.state.is_cuda
    _, on_cpu = _tables_after(200, device="cpu")
    for key, value in on_cpu.items():  # the same choices; float sums may round differently
        assert torch.allclose(value, on_gpu[key], atol=1e-4), key


def test_the_cli_trains_through_the_collector(tmp_path):
    args = ["train", "taxi", "--algo", "maxq-q", "--seeds", "2", "--envs-per-seed", "8"]
    args += ["--steps", "800", "--eval-every", "0", "--eval-episodes", "5", "--collector"]
    args += ["--out", str(tmp_path), "--no-progress", "--no-tensorboard"]
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["env_steps_per_learner"] >= 800
    direct, collected = _tables_after(100), _tables_after(100, collector=True)
    for key, value in direct[1].items():
        assert torch.equal(value, collected[1][key]), key


def _thread_warnings(threads: int) -> list[warnings.WarningMessage]:
    opts = RunOptions(seeds=[0], envs_per_learner=2, progress=False, tensorboard=False)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(threads)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            build_trainer(registry.get("taxi"), "maxq-q", opts)
    finally:
        torch.set_num_threads(before)
    return [w for w in caught if "set_num_threads(1)" in str(w.message)]


def test_a_cpu_trainer_on_more_than_one_thread_warns_at_the_users_line():
    (warning,) = _thread_warnings(2)
    assert warning.filename == __file__  # not a line inside hrl_torch
    assert not _thread_warnings(1)


def test_the_cli_sets_one_thread_for_every_command(capsys):
    torch.set_num_threads(2)
    try:
        assert main(["list"]) == 0
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(1)
