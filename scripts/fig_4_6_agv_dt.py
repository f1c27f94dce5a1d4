"""Figure 4.6: discrete-time AGV scheduling: HAR above HDR and RAR, and reaching flat RVI
Q-learning's throughput sooner.

Runs the four curves (5 seeds each, as in the text) through the CLI and writes the comparison
plots (assemblies per 1,000 steps) and a table to ``runs/fig_4_6/``.

    python scripts/fig_4_6_agv_dt.py [--seeds 5] [--steps N] [--flat-steps N]
"""

from chapter4 import agv_figure

if __name__ == "__main__":
    agv_figure("agv", "fig_4_6", "Figure 4.6, AGV, discrete time", __doc__)
