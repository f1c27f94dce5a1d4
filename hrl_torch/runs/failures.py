"""Errors of a run after its folder exists (no torch import: the CLI catches them cheaply)."""


class RunFailed(RuntimeError):
    """Training stopped on an error after the run folder was made; the message says what is left."""
