"""Layer 0: the utilities every layer uses.

Tensor ops, counter-based RNG, devices, host-read counting, sparse stores, per-learner
settings, threads, settings-as-data records, checkpoints, signals and the finder that keeps the
0.1 module paths importable. Imports nothing else of hrl_torch.
"""
