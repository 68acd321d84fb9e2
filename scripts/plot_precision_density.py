#!/usr/bin/env python3
"""Draws the precision-density trade-off written by endo_stereo_bench (--curve CSV): error rate
among output pixels (bad2, nonocc) against density, ours sweeping delta_min beside OpenCV SGBM
sweeping uniquenessRatio; one panel pooled over the scenes, one per scene.

Usage: plot_precision_density.py CURVE.csv OUT.png
"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    rows = list(csv.DictReader(open(sys.argv[1])))
    if not rows:
        sys.exit("no rows in " + sys.argv[1])
    scenes = ["pooled"] + sorted({r["scene"] for r in rows if r["scene"] != "pooled"})
    curves = defaultdict(list)  # (scene, method, knob) -> [(value, density, bad2)]
    for r in rows:
        curves[(r["scene"], r["method"], r["knob"])].append(
            (float(r["value"]), 100 * float(r["density"]), 100 * float(r["bad2"])))
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 4.0), squeeze=False)
    styles = {"ours (default)": dict(color="tab:red", marker="o"),
              "OpenCV SGBM": dict(color="tab:blue", marker="s")}
    for ax, scene in zip(axes[0], scenes):
        for (s, method, knob), pts in sorted(curves.items()):
            if s != scene:
                continue
            pts.sort()
            ax.plot([p[1] for p in pts], [p[2] for p in pts], label=f"{method} ({knob})",
                    **styles.get(method, {}))
            for value, dens, bad in (pts[0], pts[-1]):
                ax.annotate(f"{value:g}", (dens, bad), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
        ax.set_title(scene if scene != "pooled" else "pooled over scenes")
        ax.set_xlabel("density, % of nonocc pixels")
        ax.set_ylabel("bad2 among output pixels, %")
        ax.grid(True, alpha=0.3)
        ax.set_ylim(bottom=0)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)
    print("wrote", sys.argv[2])


if __name__ == "__main__":
    main()
