"""Checkpoint files: only our format loads, never by unpickling arbitrary objects."""

import pytest
import torch

from hrl_torch.common.checkpoint import FORMAT, CheckpointError, load_checkpoint, save_checkpoint


def test_round_trip_and_atomic_write(tmp_path):
    path = save_checkpoint(tmp_path / "run" / "ckpt.pt", {"step": 3, "w": torch.ones(2)})
    state = load_checkpoint(path)
    assert state["step"] == 3 and torch.equal(state["w"], torch.ones(2))
    assert not list(path.parent.glob("*.tmp"))


def test_a_torch_file_of_another_format_is_refused(tmp_path):
    torch.save({"step": 3, "w": torch.ones(2)}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not an hrl-torch/checkpoint"):
        load_checkpoint(tmp_path / "other.pt")


class Payload:
    """An object whose unpickling would run code."""

    def __reduce__(self):
        return (print, ("unpickled arbitrary code",))


def test_objects_that_need_unpickling_are_refused(tmp_path, capsys):
    torch.save({"format": FORMAT, "evil": Payload()}, tmp_path / "evil.pt")
    with pytest.raises(CheckpointError, match="corrupt or not a torch checkpoint"):
        load_checkpoint(tmp_path / "evil.pt")
    assert "unpickled arbitrary code" not in capsys.readouterr().out


def test_missing_and_truncated_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "none.pt")
    path = save_checkpoint(tmp_path / "ckpt.pt", {"step": 1})
    path.write_bytes(path.read_bytes()[:40])
    with pytest.raises(CheckpointError):
        load_checkpoint(path)


def test_resuming_a_finished_run_returns_its_result(tmp_path):
    import agents  # noqa: F401  (registers the domains)
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    opts = RunOptions(
        seeds=[0], envs_per_learner=4, steps=80, eval_every=40, eval_episodes=2, progress=False
    )

    def make():
        trainer = build_trainer(registry.get("taxi"), "maxq-q", opts)
        trainer.config.eval_max_steps = 20
        return trainer

    first = make()
    done = first.train()
    first.save(tmp_path / "ckpt.pt")
    again = make()
    again.load(tmp_path / "ckpt.pt")
    result = again.train()  # nothing left to train: the saved run's result
    assert again.step == first.step
    assert (result.final_eval, result.final_success, result.final_steps) == (
        done.final_eval,
        done.final_success,
        done.final_steps,
    )


def test_mostly_constant_tensors_are_stored_sparsely_and_come_back_bit_for_bit(tmp_path):
    table = torch.full((8, 5000, 9), -49.96)
    table[3, 17, 2], table[0, 0, 0], table[7, 4999, 8] = -0.0, float("nan"), 1.5
    state = {
        "table": table,
        "mask": torch.zeros(70_000, dtype=torch.bool).index_fill_(0, torch.tensor([5]), True),
        "counts": torch.arange(10_000) % 2,  # half differs from the fill: stays dense
        "nested": [{"w": torch.ones(4096, dtype=torch.float64)}],
    }
    path = save_checkpoint(tmp_path / "ckpt.pt", state)
    assert path.stat().st_size < 100_000  # dense: 1.66 MB, of which "counts" is 80 KB
    back = load_checkpoint(path)
    for key in ("table", "mask", "counts"):
        assert back[key].dtype == state[key].dtype and back[key].shape == state[key].shape
        bits = {1: torch.uint8, 8: torch.int64, 4: torch.int32}[state[key].element_size()]
        assert torch.equal(back[key].view(bits), state[key].view(bits)), key
    assert torch.equal(back["nested"][0]["w"], state["nested"][0]["w"])


def test_a_damaged_sparse_tensor_is_a_checkpoint_error(tmp_path):
    path = save_checkpoint(tmp_path / "ckpt.pt", {"w": torch.zeros(5000)})
    state = torch.load(path, weights_only=True)
    state["w"]["index"] = torch.tensor([10**9])
    torch.save(state, path)
    with pytest.raises(CheckpointError, match="damaged sparse tensor"):
        load_checkpoint(path)
