"""Layer 9: runs from the outside.

Domains and algorithms registered, experiments, sweeps, reports, plots, run locks, the device
check and the CLI.
"""
