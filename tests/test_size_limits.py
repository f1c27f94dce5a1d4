"""Every size that drives an allocation is checked before anything is allocated: each oversized
request of the CLI, of a run record and of a checkpoint is one line and exit code 2 in a
process whose address space is limited to 2 GiB (``ulimit -v``), where the honest run passes."""

import json
import os
import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from hrl_torch.common import limits
from hrl_torch.common.checkpoint import CheckpointError, load_checkpoint
from hrl_torch.common.sparse_store import MARK

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 2 * 2**30  # a plain `hrl-torch list` took 0.7 GiB of address space here, training 1 GiB

#: run inside the limited process: the honest run, then each case's exit code and stderr
DRIVER = textwrap.dedent(
    """
    import contextlib, io, json, shutil, sys
    import torch
    from hrl_torch.runs.cli import main
    out, cases = sys.argv[1], json.loads(sys.argv[2])

    def run(argv):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main(argv)
            except BaseException as e:  # a traceback: what the checks are there to prevent
                rc = f"raised {type(e).__name__}: {e}"
        return rc, err.getvalue()

    honest = run(["train", "taxi", "--algo", "maxq-q", "--seeds", "2", "--envs-per-seed", "4",
                  "--eval-episodes", "3", "--steps", "400", "--checkpoint-every", "200",
                  "--out", out + "/runs", "--no-progress"])
    results = {"honest": honest}
    (run_dir,) = __import__("pathlib").Path(out, "runs").iterdir()
    shutil.copytree(run_dir, f"{out}/honest")
    for name, edit in (("episodes", "record"), ("sparse", "sparse")):
        crafted = f"{out}/{name}"
        shutil.copytree(run_dir, crafted)
        state = torch.load(f"{crafted}/checkpoint.pt", weights_only=True)
        if edit == "record":
            state["run"]["eval_episodes"] = 10**9
        else:
            key = next(iter(state["trainer"]["learner"]))
            state["trainer"]["learner"][key] = {
                "__hrl_torch_sparse__": [2**28], "dtype": "float32",
                "fill": torch.tensor(0, dtype=torch.int32),
                "index": torch.zeros(0, dtype=torch.int64),
                "values": torch.zeros(0, dtype=torch.int32),
            }
        torch.save(state, f"{crafted}/checkpoint.pt")
    for name, argv in cases.items():
        results[name] = run([a.replace("OUT", out) for a in argv])
    print(json.dumps(results))
    """
)

TRAIN = ["train", "taxi", "--algo", "maxq-q", "--no-progress", "--out", "OUT/new"]
GRID = ",".join(str(0.01 + k / 200) for k in range(100))
CASES = {
    "--envs-per-seed 16777216": [*TRAIN, "--seeds", "1", "--envs-per-seed", "16777216"],
    "eval --episodes 100000000": ["eval", "OUT/honest", "--episodes", "100000000"],
    "--eval-episodes 100000000": [*TRAIN, "--eval-episodes", "100000000"],
    "--set envs_per_learner=100000000": [*TRAIN, "--set", "envs_per_learner=100000000"],
    "--seeds 100000 --envs-per-seed 1": [*TRAIN, "--seeds", "100000", "--envs-per-seed", "1"],
    "sweep --population 100 x 100 x 5 seeds": [
        "sweep",
        "taxi",
        "--algo",
        "maxq-q",
        "--population",
        "--seeds",
        "5",
        "--out",
        "OUT/sw",
        "--grid",
        f"learner.alpha={GRID}",
        "--grid",
        f"exploration.epsilon.end={GRID}",
    ],  # fmt: skip
    "a record with eval_episodes=10**9": ["eval", "OUT/episodes"],
    "a record with eval_episodes=10**9, resumed": [
        "train",
        "--resume",
        "OUT/episodes/checkpoint.pt",
        "--steps",
        "800",
        "--no-progress",
    ],  # fmt: skip
    "a sparse tensor of 2**28 entries": ["eval", "OUT/sparse"],
    "a sparse tensor of 2**28 entries, resumed": [
        "train",
        "--resume",
        "OUT/sparse/checkpoint.pt",
        "--steps",
        "800",
        "--no-progress",
    ],  # fmt: skip
}


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("limited")
    env = dict(os.environ, PYTHONPATH=str(ROOT), RL_LOGGING_LEVEL="WARNING")
    done = subprocess.run(
        [sys.executable, "-c", DRIVER, str(out), json.dumps(CASES)],
        preexec_fn=_limited,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_honest_run_passes_under_the_limit(results):
    rc, err = results["honest"]
    assert rc == 0, err


@pytest.mark.parametrize("case", list(CASES))
def test_an_oversized_request_is_one_line_under_a_2_gib_address_space(case, results):
    rc, err = results[case]
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, (rc, err[-2000:])
    assert lines[0].startswith("hrl-torch: error: "), lines
    assert any(word in lines[0] for word in ("more than", "needs about")), lines


def test_the_budget_follows_the_address_space_limit():
    budget, source = limits.memory_budget()
    assert budget > 0 and source
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    try:  # lowered in this process for a moment: the budget is what is left under it
        resource.setrlimit(resource.RLIMIT_AS, (limits._vm_size() + 2**28, hard))
        low, source = limits.memory_budget()
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    assert low <= 2**28 and source == "address space left under ulimit -v"
    with pytest.raises(limits.SizeLimitError, match="needs about 1,024.0 GiB"):
        limits.check_bytes("a table", 2**40, "use a smaller one")


def test_a_checkpoint_declaring_a_huge_sparse_tensor_is_refused_before_it_is_built(tmp_path):
    path = tmp_path / "crafted.pt"
    empty = torch.zeros(0, dtype=torch.int64)
    packed = {MARK: [2**40], "dtype": "float32", "fill": torch.tensor(0, dtype=torch.int32),
              "index": empty, "values": empty.int()}  # fmt: skip
    torch.save({"format": "hrl-torch/checkpoint/2", "trainer": {"learner": {"Q": packed}}}, path)
    with pytest.raises(CheckpointError, match="declared shapes"):
        load_checkpoint(path)
