import os
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")
torch.set_num_threads(1)


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    """A small trained taxi run folder (``tests/run_folders.py``): copy it, never edit it."""
    from tests.run_folders import the_run, train

    out = tmp_path_factory.mktemp("trained_run")
    assert train(out) == 0
    return the_run(out)
