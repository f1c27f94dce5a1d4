"""The one-thread rule of the CPU hot path, and the warning that enforces it."""

from __future__ import annotations

import os
import sys
import warnings

import torch


def warn_cpu_threads(device) -> None:
    """Warn when torch runs this CPU hot path on more than one thread.

    A step is many small ops. On an idle machine two threads were no slower, but with another
    process on a core a taxi step at 10 x 512 was 9-75x slower (docs/design.md#threads). The
    CLI sets one thread itself.
    """
    if torch.device(device).type == "cpu" and torch.get_num_threads() > 1:
        warnings.warn(
            f"torch uses {torch.get_num_threads()} threads: the batched hot path (many small "
            "ops) slows down many times over when another process shares a core; call "
            "torch.set_num_threads(1) before training",
            stacklevel=_first_caller_outside_package(),
        )


def _first_caller_outside_package() -> int:
    """``stacklevel`` for a warning raised by our caller: the first frame outside hrl_torch."""
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep  # hrl_torch/
    frame, level = sys._getframe(1), 1  # level 1: the function that calls warnings.warn
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level
