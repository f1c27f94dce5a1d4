"""Figure 4.7: continuous-time AGV scheduling: HAR close to HDR, both above RAR, and HAR
faster than (continuous-time) RVI Q-learning.

Runs the four curves (5 seeds each, as in the text) through the CLI and writes the comparison
plots (assemblies per 1,000 s) and a table to ``runs/fig_4_7/``.

    python scripts/fig_4_7_agv_ct.py [--seeds 5] [--steps N] [--flat-steps N]
"""

from chapter4 import agv_figure

if __name__ == "__main__":
    agv_figure("agv-ct", "fig_4_7", "Figure 4.7, AGV, continuous time", __doc__)
