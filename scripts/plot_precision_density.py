#!/usr/bin/env python3
"""Draws the precision-density trade-off written by endo_stereo_bench (--curve CSV): error rate
among output pixels (bad2, nonocc) against density, ours sweeping delta_min (the paper's knob) and
edge_disparity_jump_px (our edge test's threshold) beside OpenCV SGBM sweeping uniquenessRatio;
one panel pooled over the scenes, one per scene. Numbers at the curve ends are the knob values.

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
    styles = {"delta_min": dict(color="tab:red", marker="o"),
              "edge_disparity_jump_px": dict(color="tab:orange", marker="^"),
              "uniquenessRatio": dict(color="tab:blue", marker="s")}
    for ax, scene in zip(axes[0], scenes):
        for (s, method, knob), pts in sorted(curves.items()):
            if s != scene:
                continue
            pts.sort()
            ax.plot([p[1] for p in pts], [p[2] for p in pts], label=f"{method} ({knob})",
                    **styles.get(knob, {}))
            for value, dens, bad in (pts[0], pts[-1]):
                ax.annotate(f"{value:g}", (dens, bad), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
        # A strict setting can leave almost nothing (SGBM at uniquenessRatio 100 keeps ~5%); such
        # points are in the CSV and the table, the axis shows the range where the curves compete.
        ours = [p[1] for (s, m, k), pts in curves.items() if s == scene and m.startswith("ours")
                for p in pts]
        if ours:
            ax.set_xlim(left=max(0.0, min(ours) - 10.0), right=100.0)
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
