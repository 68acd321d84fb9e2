#!/usr/bin/python3
"""The depth-edge filter's trade-off on the real recordings: density against trust, one point per
setting of its thresholds, with OpenCV BM and SGBM on the same frames (docs/method.md, section
5.1; docs/decisions/edge-thresholds-on-real-video.md says why the default sits where it does).

For each setting it runs, through `Pipeline` as users do:
  - endo_stereo_evaluate on the in-vivo video (all frames, search 0..127, ours with priors):
    density, raw jumps, motion-compensated flicker, central coverage;
  - endo_stereo_eval --peers on the SCARED keyframe with structured-light ground truth (search
    0..95) and the Middlebury scenes: bad2 and density per pair.
The peers come from the same runs (they do not depend on our settings).

Writes OUT/edge_tradeoff.json, the picture PNG (density on the x axis; flicker, jumps, SCARED
bad2, worst Middlebury bad2 and coverage on the y axes, each target drawn) and prints a Markdown
table.

Usage: edge_tradeoff.py --bin DIR --real DIR --out DIR --png FILE [--threads N]
Needs ../shared/data/real (the in-vivo video and the SCARED keyframe); Middlebury is optional.
"""
import argparse
import json
import os
import subprocess
import sys

# label, --set arguments: the jump thresholds below / above ("j"), the margin ("m", the default
# preset's 6 px where not named) and the filter off, around the default preset (no --set).
SETTINGS = [
    ("j 2/4", ["matcher.edge_disparity_jump_px=2", "matcher.edge_disparity_jump_above_px=4"]),
    ("j 2.5/5", ["matcher.edge_disparity_jump_px=2.5", "matcher.edge_disparity_jump_above_px=5"]),
    ("j 3/6, m 7", ["matcher.edge_margin_px=7"]),
    ("j 3/6, m 6 (default)", []),
    ("j 3/6, m 5", ["matcher.edge_margin_px=5"]),
    ("j 3/6, m 3", ["matcher.edge_margin_px=3"]),
    ("j 3.5/7", ["matcher.edge_disparity_jump_px=3.5", "matcher.edge_disparity_jump_above_px=7"]),
    ("j 4/8", ["matcher.edge_disparity_jump_px=4", "matcher.edge_disparity_jump_above_px=8"]),
    ("j 5/10", ["matcher.edge_disparity_jump_px=5", "matcher.edge_disparity_jump_above_px=10"]),
    ("filter off", ["matcher.edge_disparity_jump_px=0"]),
]
MIDDLEBURY = ("tsukuba", "venus", "teddy")
# The targets of the dense-tissue requirement (README, status): flicker no higher than BM's,
# raw jumps <= 3%, SCARED bad2 <= 0.3% at >= 92% density, Middlebury bad2 <= 2% on every scene,
# coverage >= 97%, density >= SGBM's.
JUMPS_MAX, SCARED_MAX, SCARED_DENSITY_MIN, MIDDLEBURY_MAX, COVERAGE_MIN = 0.03, 0.003, 0.92, 0.02, 0.97


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("edge_tradeoff.py: failed (%d): %s\n%s" % (r.returncode, " ".join(cmd), r.stderr[-2000:]))


def sets(args):
    out = []
    for s in args:
        out += ["--set", s]
    return out


def measure(a, label, extra, tag, with_peers):
    inv = os.path.join(a.out, "edge_tradeoff_%s_invivo.json" % tag)
    gt = os.path.join(a.out, "edge_tradeoff_%s_gt.json" % tag)
    real = a.real
    run([os.path.join(a.bin, "endo_stereo_evaluate"),
         "--left", os.path.join(real, "hamlyn_invivo1/left/%04d.png"),
         "--right", os.path.join(real, "hamlyn_invivo1/right/%04d.png"),
         "--min-disparity", "0", "--max-disparity", "127", "--methods", "ours,bm,sgbm" if with_peers else "ours",
         "--threads", str(a.threads), "--quiet", "--json", inv] + sets(extra))
    run([os.path.join(a.bin, "endo_stereo_eval"), "--peers", "--json", gt,
         "--gt-pair", os.path.join(real, "scared_ds1_kf2_gt"), "--gt-range", "0:95"] + sets(extra))
    ev = json.load(open(inv))
    g = json.load(open(gt))
    rows = {}
    for m in ev["methods"]:
        rows[m["key"]] = {"density": m["density_mean"], "jumps": m["jump_share"],
                          "flicker": m["flicker_share"], "coverage": m["coverage_every_window"]}
    name_of = {"ours": "ours", "OpenCV BM": "bm", "OpenCV SGBM": "sgbm"}
    for p in g["pairs"]:
        key = "scared" if p["pair"].startswith("scared") else p["pair"]
        for m in p["methods"]:
            k = name_of.get(m["method"])
            if k in rows:
                rows[k][key + "_bad2"] = m["bad2"]
                rows[k][key + "_density"] = m["density"]
    for r in rows.values():
        mb = [(r[s + "_bad2"], s) for s in MIDDLEBURY if s + "_bad2" in r]
        if mb:
            r["middlebury_worst_bad2"], r["middlebury_worst"] = max(mb)
    rows["ours"]["label"] = label
    rows["ours"]["set"] = extra
    return rows


def pct(v, d=1):
    return "n/a" if v is None else ("%." + str(d) + "f") % (100 * v)


def row(name, q, crossed):
    """One table row: the figures of q (a setting or a peer), then the bounds column."""
    middlebury = ("%s (%s)" % (pct(q["middlebury_worst_bad2"], 2), q["middlebury_worst"])
                  if "middlebury_worst_bad2" in q else "n/a")
    print("| %s | %s | %s | %s | %s | %s at %s | %s |%s|" % (
        name, pct(q["density"]), pct(q["jumps"], 2), pct(q["flicker"], 2), pct(q["coverage"]),
        pct(q.get("scared_bad2"), 2), pct(q.get("scared_density"), 2), middlebury,
        " %s " % crossed if crossed else " "))


def table(points, peers):
    print("| setting | in-vivo density % | jumps > 2 px % | flicker % | central covered every 10"
          " frames % | SCARED bad2 % at density % | worst Middlebury bad2 % (scene) | bounds crossed |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    bm_flicker = peers["bm"]["flicker"]
    for p in points:
        crossed = []
        if p["flicker"] > bm_flicker:
            crossed.append("flicker")
        if p["jumps"] > JUMPS_MAX:
            crossed.append("jumps")
        if p.get("scared_bad2", 0) > SCARED_MAX or p.get("scared_density", 1) < SCARED_DENSITY_MIN:
            crossed.append("SCARED")
        if p.get("middlebury_worst_bad2", 0) > MIDDLEBURY_MAX:
            crossed.append("Middlebury")
        name = "**%s**" % p["label"] if "default" in p["label"] else p["label"]
        row(name, p, ", ".join(crossed) or "none")
    for k, name in (("bm", "OpenCV BM"), ("sgbm", "OpenCV SGBM")):
        row(name, peers[k], "")


def plot(points, peers, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = [("flicker", "motion-compensated flicker %", peers["bm"]["flicker"], "<= BM's"),
              ("jumps", "jumps > 2 px %", JUMPS_MAX, "<= 3%"),
              ("scared_bad2", "SCARED keyframe bad2 %", SCARED_MAX, "<= 0.3%"),
              ("middlebury_worst_bad2", "worst Middlebury bad2 %", MIDDLEBURY_MAX, "<= 2%"),
              ("coverage", "central covered every 10 frames %", COVERAGE_MIN, ">= 97%")]
    from matplotlib.ticker import FuncFormatter, NullFormatter
    fig, grid = plt.subplots(2, 3, figsize=(13.5, 8.0))
    axes = list(grid.flat)
    points = sorted(points, key=lambda p: p["density"])
    xs = [100 * p["density"] for p in points]
    for ax, (key, title, bound, bound_txt) in zip(axes, panels):
        ys = [100 * p[key] if key in p else float("nan") for p in points]
        ax.plot(xs, ys, "o-", color="tab:blue", label="ours, one point per setting")
        for p, x, y in zip(points, xs, ys):
            if "default" in p["label"]:
                ax.plot([x], [y], "o", ms=11, mfc="none", mec="black", label="default preset")
            ax.annotate(p["label"].replace(" (default)", ""), (x, y), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
        for k, name, style in (("bm", "OpenCV BM", "s"), ("sgbm", "OpenCV SGBM", "^")):
            if key in peers[k]:
                ax.plot([100 * peers[k]["density"]], [100 * peers[k][key]], style, color="tab:red"
                        if k == "sgbm" else "tab:green", label=name)
        ax.axhline(100 * bound, color="gray", ls="--", lw=1, label="target " + bound_txt)
        ax.axvline(100 * peers["sgbm"]["density"], color="tab:red", ls=":", lw=1,
                   label="density target (SGBM's)")
        if key == "flicker":  # BM to the filter off spans two decades
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: "%g" % v))
            ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("in-vivo density per frame %")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    axes[-1].axis("off")
    axes[-1].legend(handles, [l.replace("<= BM's", "(each panel's bound)") for l in labels],
                    loc="center", fontsize=9, frameon=False)
    fig.suptitle("The depth-edge filter's thresholds: in-vivo density against trust"
                 " (j below/above px, m margin px)", fontsize=10)
    fig.tight_layout()
    fig.savefig(png, dpi=90)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", required=True)
    ap.add_argument("--real", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--png", required=True)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    if not os.path.isdir(os.path.join(a.real, "hamlyn_invivo1")) or \
            not os.path.isdir(os.path.join(a.real, "scared_ds1_kf2_gt")):
        sys.exit("edge_tradeoff.py: %s lacks hamlyn_invivo1 or scared_ds1_kf2_gt" % a.real)
    os.makedirs(a.out, exist_ok=True)
    points, peers = [], None
    for i, (label, extra) in enumerate(SETTINGS):
        print("edge_tradeoff.py: %s" % label, file=sys.stderr)
        # The in-vivo peers once, with the default setting (they do not read our settings).
        default = "default" in label
        rows = measure(a, label, extra, "default" if default else "s%d" % i, default)
        points.append(rows["ours"])
        if "bm" in rows and "density" in rows["bm"]:
            peers = rows
    json.dump({"points": points, "peers": {k: peers[k] for k in ("bm", "sgbm")}},
              open(os.path.join(a.out, "edge_tradeoff.json"), "w"), indent=1)
    table(points, peers)
    plot(points, peers, a.png)


if __name__ == "__main__":
    main()
