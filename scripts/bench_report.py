#!/usr/bin/python3
"""Writes BENCHMARKS.md, docs/benchmark_results.json and docs/bench_*.png from one run of
scripts/bench.sh (its outputs in out/bench and out/bench_ros). `make bench` calls it last; run it
alone to rebuild the page from the outputs already there:

  scripts/bench_report.py [--out out/bench] [--ros out/bench_ros] [--root .]
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import time

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def git(*args):
    r = subprocess.run(["git", "-C", ROOT] + list(args), capture_output=True, text=True)
    return r.stdout.strip() if r.returncode == 0 else ""


def pct(v, digits=1):
    return "n/a" if v is None else ("%." + str(digits) + "f") % (100.0 * v)


def num(v, fmt="%.1f"):
    return "n/a" if v is None else fmt % v


def machine_line(m):
    threads = m.get("opencv_threads", 0)
    return "%s, %d logical CPUs, OpenCV %s (%d thread%s); load average %s at the start, %s at the end" % (
        m.get("cpu", "?"), m.get("logical_cpus", 0), m.get("opencv", "?"),
        threads, "" if threads == 1 else "s", m.get("load_average_start", "?").split()[0],
        m.get("load_average_end", "?").split()[0])


def busy(m):
    """True when the 1-minute load average exceeded the CPU count at the start or the end."""
    try:
        n = float(m.get("logical_cpus", 1))
        return max(float(m["load_average_start"].split()[0]),
                   float(m["load_average_end"].split()[0])) > n
    except (KeyError, ValueError, IndexError):
        return False


class Page:
    def __init__(self, commands, commit, dirty):
        self.lines = []
        self.commands = commands
        self.commit = commit + (" with uncommitted changes" if dirty else "")
        self.any_busy = False

    def add(self, *lines):
        self.lines.extend(lines)

    def provenance(self, cmd_id, machine=None, extra=None):
        cmd = self.commands.get(cmd_id)
        if cmd:
            self.add("Command: `%s`  " % cmd)
        text = "Commit %s" % self.commit
        if machine:
            text += "; " + machine_line(machine)
            if busy(machine):
                self.any_busy = True
                text += " (**busy machine: times not representative**)"
        if extra:
            text += "; " + extra
        self.add(text + ".", "")


def evaluation_table(page, ev):
    # An evaluation.json without flicker_share (an older tool) shows n/a.
    page.add("| method | density median %% | density mean %% | jumps > %g px %% |"
             " motion-compensated flicker > %g px %% | central covered every %d frames %% |"
             " central never %% |"
             " ms/frame median | time / SGBM | CPU ms median |"
             % (ev["jump_px"], ev["jump_px"], ev["window_frames"]),
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for m in ev["methods"]:
        timed = "ms_median" in m
        page.add("| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            m["name"], pct(m["density_median"]), pct(m["density_mean"]), pct(m["jump_share"], 2),
            pct(m.get("flicker_share"), 2),
            pct(m["coverage_every_window"]), pct(m["coverage_never"]),
            num(m.get("ms_median")) if timed else "-",
            num(m.get("time_over_sgbm"), "%.2f") if timed else "-",
            num(m.get("cpu_ms_median")) if timed else "-"))
    page.add("")


def ros_table(page, runs):
    """One row per stream and node; each cell lists every run (run 1 / run 2 / ...)."""
    page.add("| stream | node | pairs in | outputs | dropped (nodelet's own count) | output rate Hz | latency median ms | latency p90 ms | density |",
             "|---|---|---:|---:|---|---:|---:|---:|---:|")
    groups = {}  # (case, node) -> its runs, in the order bench_ros.sh ran them
    for r in runs:
        groups.setdefault((r["case"], r["node"]), []).append(r)
    for rs in groups.values():
        rs.sort(key=lambda r: r.get("run", 1))
        r = rs[0]

        def col(key, fmt="%s"):
            return " / ".join(num(x.get(key), fmt) for x in rs)
        node = "endo_stereo (default preset)" if r["node"] == "endo_stereo" else "stereo_image_proc (SGBM)"
        dropped = col("dropped_or_lost")
        if any(x.get("nodelet_pairs_dropped") is not None for x in rs):
            dropped += " (%s dropped, %s rejected)" % (col("nodelet_pairs_dropped"),
                                                      col("nodelet_pairs_rejected"))
        page.add("| %s, %d frames, %d..%d | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            r["description"], r["frames"], r["min_disparity"], r["max_disparity"], node,
            col("pairs_in"), col("outputs"), dropped, col("output_rate_hz", "%.1f"),
            col("latency_median_ms", "%.1f"), col("latency_p90_ms", "%.1f"),
            col("density_mean", "%.3f")))
    page.add("")


def ros_runs_line(ros, runs):
    """How many times each bag was played through each node (as the cells list them)."""
    n = ros.get("runs_per_node") or max([r.get("run", 1) for r in runs] or [1])
    if n == 1:
        return "Each bag played once through each node."
    return ("Each bag played %d times through each node, the nodes taking turns; each cell lists"
            " the runs in order (run 1 / run 2%s)." % (n, " / ..." if n > 2 else ""))


# The stages of Pipeline::process in endo_stereo_evaluate's stage_ms_median.
STAGES = (("rectify_preprocess", "pre-processing and rectification"),
          ("priors", "priors, fusion, coverage (temporal stage)"),
          ("prepare", "matcher: preparation"),
          ("search", "matcher: search"),
          ("edge", "matcher: depth-edge filter"),
          ("filters", "matcher: post-filters"),
          ("rest", "the rest"),
          ("total", "**total**"))


def stage_table(page, pairs):
    """Rows: stages; columns: recording x (with, without priors); cells: ms at 1 / N threads.
    pairs: (short name, evaluation at 1 thread or None, evaluation at the default count or None)."""
    cols = []
    for name, one, many in pairs:
        for key, what in (("ours", "priors"), ("ours-no-priors", "no priors")):
            a = next((m for m in (one or {}).get("methods", []) if m["key"] == key), None)
            b = next((m for m in (many or {}).get("methods", []) if m["key"] == key), None)
            if (a and "stage_ms_median" in a) or (b and "stage_ms_median" in b):
                threads = ((one or {}).get("machine", {}).get("opencv_threads", "?"),
                           (many or {}).get("machine", {}).get("opencv_threads", "?"))
                cols.append(("%s, %s" % (name, what), threads,
                             (a or {}).get("stage_ms_median", {}),
                             (b or {}).get("stage_ms_median", {})))
    if not cols:
        return False
    thread_sets = {c[1] for c in cols}
    same = len(thread_sets) == 1
    if same:
        page.add("Each cell: ms at %s / %s threads." % next(iter(thread_sets)), "")
    page.add("| stage, ms (median) | " + " | ".join(
        c[0] + ("" if same else " (%s / %s threads)" % c[1]) for c in cols) + " |",
        "|---|" + "---:|" * len(cols))
    for key, label in STAGES:
        page.add("| %s | %s |" % (label, " | ".join(
            "%s / %s" % (num(a.get(key), "%.1f"), num(b.get(key), "%.1f")) for _, _, a, b in cols)))
    speedups = []
    for _, _, a, b in cols:
        ta, tb = a.get("total"), b.get("total")
        speedups.append("%.2fx" % (ta / tb) if ta and tb else "n/a")
    page.add("| speed-up of the total | %s |" % " | ".join(speedups), "")
    return True


def demote(md_text):
    """The printed tables of endo_stereo_bench, headings moved two levels down, title dropped."""
    out = []
    for line in md_text.splitlines():
        if line.startswith("# "):
            continue
        if line.startswith("## Precision-density sweep"):
            break  # the sweep is in docs/precision_density.{csv,png}
        if line.startswith("## "):
            line = "#### " + line[3:]
        out.append(line)
    while out and not out[-1].strip():
        out.pop()
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--ros", default="out/bench_ros")
    a = ap.parse_args()
    os.chdir(ROOT)
    commands = {}
    if os.path.exists(os.path.join(a.out, "commands.tsv")):
        for line in open(os.path.join(a.out, "commands.tsv")):
            if "\t" in line:
                k, v = line.rstrip("\n").split("\t", 1)
                commands[k] = v
    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    # Uncommitted changes to anything but this run's own outputs make the commit an approximation.
    outputs = ("BENCHMARKS.md", "docs/benchmark_results.json", "docs/precision_density.csv",
               "docs/precision_density.png", "docs/bench_invivo.png", "docs/bench_generated.png",
               "docs/edge_tradeoff.png")
    dirty = any(line.split(None, 1)[-1] not in outputs
                for line in git("status", "--porcelain", "--untracked-files=no").splitlines())
    page = Page(commands, commit, dirty)
    ev = {k: load(os.path.join(a.out, k, "evaluation.json"))
          for k in ("invivo", "real960_static", "real960_moving", "generated")}
    ev_t1 = {k: load(os.path.join(a.out, k + "_t1.json")) for k in ("invivo", "real960_moving")}
    gt = load(os.path.join(a.out, "groundtruth.json"))
    tradeoff = load(os.path.join(a.out, "edge_tradeoff.json"))
    scenes = load(os.path.join(a.out, "scenes.json"))
    ros = load(os.path.join(a.ros, "ros_bench.json")) or {"runs": []}
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    any_machine = next((e["machine"] for e in ev.values() if e), None)

    page.add("# Benchmarks", "",
             "Written by `make bench` (scripts/bench.sh, then scripts/bench_report.py, on %s): every"
             " figure below comes from that one run; edit the scripts, not this page. The raw"
             " results are in [docs/benchmark_results.json](docs/benchmark_results.json)." % date, "",
             "- Commit: %s." % page.commit,
             "- Machine: %s." % (machine_line(any_machine) if any_machine else "see the tables"),
             "- Real recordings come from `../shared/data/real` beside the repository (its README"
             " names the sources); without it `make bench` says so and writes the generated"
             " tables only.",
             "- Times are wall-clock medians per frame on this machine; ratios to OpenCV SGBM"
             " measured in the same process on the same frames are the figures to compare across"
             " machines. When the load average exceeds the CPU count the table says so: its times"
             " are then not representative. CPU ms above the wall time means more than one core"
             " worked; below it, the process waited for a core.", "")

    page.add("## Definitions", "",
             "On a recording without ground truth (`endo_stereo_evaluate`, README: \"Evaluating a"
             " recording\"), each method's disparity maps, frame by frame:",
             "- **density**: share of the frame's pixels with a value (per frame; median and mean over"
             " frames);",
             "- **jumps**: among pixels with a value in two consecutive frames, the share whose"
             " disparity changed by more than 2 px (pooled over all frame pairs). On slowly moving"
             " tissue such a jump is almost always an error;",
             "- **motion-compensated flicker**: for each pair of consecutive frames and each pixel"
             " with a value in both, its change d_t - d_{t-1} minus the mean change of the pixels"
             " with a value in both within the 17x17 square centred on it (the pixel itself"
             " included, the square cut at the image border); the share of those pixels where the"
             " absolute value exceeds 2 px (pooled over all frame pairs, like the jumps). Motion"
             " shared by the neighbourhood (breathing, a camera pan) cancels; a pixel that changes"
             " alone does not;",
             "- **coverage**: share of the central pixels (the middle half of the image in each"
             " direction) with a value in every window of 10 consecutive frames; **never**: without"
             " a value in any frame;",
             "- **ours, fused output**: the pipeline's temporally fused map (the latest value measured"
             " within `temporal.fused_max_age_frames`); the lines without \"fused\" count only values"
             " measured on that frame;",
             "- ours: `Pipeline` with the built-in defaults (as `endo_stereo_cli`), with temporal"
             " priors and without; time = the whole `Pipeline::process` call (2 threads). OpenCV BM:"
             " blockSize 15, uniquenessRatio 15; SGBM (MODE_SGBM): blockSize 5, P1 200, P2 800,"
             " uniquenessRatio 10; every other setting OpenCV's default; time = `compute()` on the"
             " same rectified gray pair. OpenCV searches a multiple of 16 disparities and gives no"
             " value in the leftmost columns where the search would leave the image.",
             "", "With ground truth (`endo_stereo_eval --peers`): bad2 / bad3 = share of output pixels"
             " off by more than 2 / 3 px, mean error over output pixels, density = output pixels /"
             " ground-truth pixels in the mask (SCARED: occlusion mask = 255; Middlebury: nonocc).", "")

    # --- 1. real -------------------------------------------------------------------------------
    page.add("## 1. Real recordings", "")
    if not any(ev[k] for k in ("invivo", "real960_static", "real960_moving")):
        page.add("Not measured in this run: `../shared/data/real` was absent.", "")
    if ev["invivo"]:
        e = ev["invivo"]
        page.add("### 1.1 In-vivo video: real/hamlyn_invivo1, %d frames %dx%d, search %d..%d" % (
            e["frames"], e["width"], e["height"], e["min_disparity"], e["max_disparity"]), "",
            "A live da Vinci recording (Hamlyn Centre, rectified): bleeding tissue, specular"
            " highlights, two instruments, breathing motion.", "")
        page.provenance("invivo", e["machine"])
        evaluation_table(page, e)
        page.add("Frame %d: the left image, each method's disparity on one colour scale (0..%d px),"
                 " the pixels that jumped since the previous frame, the pixels that flickered"
                 " (motion-compensated), and each method's coverage map over the whole sequence:"
                 % (e["picture_frame"] + 1, e["max_disparity"]), "",
                 "![in-vivo comparison](docs/bench_invivo.png)", "")
    if ev["real960_static"] or ev["real960_moving"]:
        page.add("### 1.2 A real frame at 960x540: SCARED dataset 1, search 48..111", "",
                 "The raw 1280x1024 da Vinci Xi pair of real/scared_ds1_pair, rectified with its"
                 " published calibration by `endo_stereo_cli --calib`, then cut to its centre 960x540 (the paper's working size) by"
                 " `endo_stereo_evaluate --crop`. Two sequences are made from this one pair:", "",
                 "- **static**: the same pair 10 times. Ours without priors searches the full range"
                 " on every frame: its time is the full-search time; with priors, frames after the"
                 " first search narrowed ranges;",
                 "- **moving**: 75 frames in which the 960x540 crop window moves on a circle of"
                 " radius 24 px around the centre, one turn in 75 frames (3 s at 25 fps, about 2 px"
                 " per frame): a slow camera pan over real tissue. Every frame is an exact crop of"
                 " the rectified pair (integer offsets, no resampling); the tissue itself does not"
                 " deform.", "")
        page.add("Rectification: `%s`" % commands.get("scared_rectify", "n/a"), "")
        for key, title in (("real960_static", "Static (full search)"), ("real960_moving", "Moving crop")):
            e = ev[key]
            if not e:
                continue
            page.add("#### %s: %d frames" % (title, e["frames"]), "")
            page.provenance(key, e["machine"])
            evaluation_table(page, e)
        page.add("No picture of the SCARED frames is published here: the data is for evaluation,"
                 " not for redistribution.", "")
    if any(ev_t1.values()):
        # The other runs use OpenCV's default thread count (one per CPU).
        many = next((ev[k]["machine"].get("opencv_threads") for k in ("invivo", "real960_moving")
                     if ev[k]), "N")
        page.add("### 1.3 Time per stage at 1 and %s threads" % many, "",
                 "Our pipeline's time per frame (`Pipeline::process`, the ms/frame median of 1.1"
                 " and 1.2) split into its stages, each the median over the same frames (the"
                 " medians need not add up to the total exactly). The 1-thread runs repeat the"
                 " in-vivo video and the moving 960x540 crop with `--threads 1`, ours only.", "")
        for key in ("invivo", "real960_moving"):
            if ev_t1[key]:
                page.provenance(key + "_t1", ev_t1[key]["machine"])
        stage_table(page, (("in-vivo 360x288", ev_t1["invivo"], ev["invivo"]),
                           ("SCARED 960x540 moving", ev_t1["real960_moving"],
                            ev["real960_moving"])))
        page.add("Search: every pass (narrowed ranges, the fallback, a scene change's second"
                 " go) and every window size. Depth-edge filter: the measure against window"
                 " fattening at depth edges. The rest: the call's wall time less the stages"
                 " above. Speed-up: total at 1 thread / total at %s threads." % many, "")
    if gt:
        page.add("### 1.4 Pairs with ground truth", "")
        page.provenance("groundtruth", any_machine,
                        "each time is one run (not a median): a rough figure")
        page.add("| pair | method | bad2 % | bad3 % | mean error px | density % | ms |",
                 "|---|---|---:|---:|---:|---:|---:|")
        pairs = sorted(gt["pairs"], key=lambda p: 0 if p["pair"].startswith("scared") else 1)
        for p in pairs:
            for m in p["methods"]:
                page.add("| %s %dx%d, %d..%d | %s | %s | %s | %s | %s | %s |" % (
                    p["pair"], p["width"], p["height"], p["min_disparity"], p["max_disparity"],
                    m["method"], pct(m["bad2"], 2), pct(m["bad3"], 2),
                    num(m["mean_abs_error_px"], "%.2f"), pct(m["density"]), num(m["ms"])))
        page.add("", "scared_ds1_kf2_gt: a rectified SCARED keyframe with structured-light ground"
                 " truth (590x512). Middlebury tsukuba, venus, teddy: search 0..their largest"
                 " disparity.", "")
    real_ros = [r for r in ros["runs"] if r["case"] in ("invivo", "real960")]
    if real_ros:
        page.add("### 1.5 The nodelet on real streams at 25 fps", "",
                 "The in-vivo frames and the moving 960x540 SCARED crop (100 frames, the same"
                 " circle) as bags (scripts/frames_to_bag.py: rectified camera_info), played with"
                 " `rosbag play` through endo_stereo's node and Debian's stereo_image_proc (SGBM,"
                 " block size 7), one after the other, same disparity range. "
                 + ros_runs_line(ros, real_ros), "")
        page.provenance("bench_ros", None, "%s CPUs, load average %s at the end; %s" % (
            ros.get("cpus"), ros.get("load_average_end"), ros.get("date")))
        ros_table(page, real_ros)
        page.add("Latency: the left image's arrival at a listener node to the arrival of the"
                 " disparity with the same stamp at that listener. Dropped: pairs in without an"
                 " output.", "")

    tradeoff_md = os.path.join(a.out, "edge_tradeoff.md")
    if tradeoff and os.path.exists(tradeoff_md):
        page.add("### 1.6 Density against trust: the depth-edge filter's thresholds", "",
                 "The in-vivo figures of 1.1 and the ground-truth figures of 1.4 again for each"
                 " setting of the depth-edge filter around the default preset (j: jump below /"
                 " above, px; m: margin, px, 6 where not named), all through `Pipeline`, beside"
                 " OpenCV BM and SGBM. A bound is crossed when flicker exceeds BM's, jumps exceed"
                 " 3%, SCARED bad2 exceeds 0.3% or its density falls under 92%, or a Middlebury"
                 " scene exceeds 2% bad2. Why the default sits where it does:"
                 " [docs/decisions/edge-thresholds-on-real-video.md]"
                 "(docs/decisions/edge-thresholds-on-real-video.md).", "")
        page.provenance("edge_tradeoff", any_machine)
        page.add(*open(tradeoff_md).read().rstrip("\n").split("\n"))
        page.add("", "![the depth-edge filter's trade-off](docs/edge_tradeoff.png)", "")

    # --- 2. generated --------------------------------------------------------------------------
    page.add("## 2. Generated scenes", "")
    if ev["generated"]:
        e = ev["generated"]
        page.add("### 2.1 A generated surgical sequence: %d frames %dx%d, search %d..%d" % (
            e["frames"], e["width"], e["height"], e["min_disparity"], e["max_disparity"]), "",
            "endo_stereo_generate (deforming textured tissue, vessels, highlights, a moving"
            " instrument; `%s`)." % commands.get("generate", "n/a"), "")
        page.provenance("generated", e["machine"])
        evaluation_table(page, e)
        page.add("![generated comparison](docs/bench_generated.png)", "")
    scenes_md = os.path.join(a.out, "scenes.md")
    if scenes and os.path.exists(scenes_md):
        page.add("### 2.2 Scenes with ground truth, beside OpenCV's quasi-dense matcher", "",
                 "endo_stereo_bench: Middlebury and two synthetic scenes with exact ground truth"
                 " (nonocc mask, errors among output pixels), our default and paper presets"
                 " (matcher only) beside OpenCV BM (blockSize 9, the settings of OpenCV's"
                 " stereo_match sample), SGBM and cv::stereo::QuasiDenseStereo; then the 960x540"
                 " timing case; the precision-density sweep is plotted in"
                 " [docs/precision_density.png](docs/precision_density.png)"
                 " ([csv](docs/precision_density.csv)).", "")
        m = {"cpu": scenes.get("cpu"), "logical_cpus": any_machine.get("logical_cpus", 0) if any_machine else 0,
             "opencv": scenes.get("opencv"), "opencv_threads": scenes.get("opencv_threads", 0),
             "load_average_start": scenes.get("load_average_start", "?"),
             "load_average_end": scenes.get("load_average_start", "?")}
        page.provenance("scenes", m, "%d repetitions per timing (median)" % scenes.get("repeats", 0))
        page.add(*[l for l in demote(open(scenes_md).read()) if not l.startswith("machine:")])
        page.add("")
    gen_ros = [r for r in ros["runs"] if r["case"] == "synthetic"]
    if gen_ros:
        page.add("### 2.3 The nodelet on a generated stream at 25 fps", "",
                 ros_runs_line(ros, gen_ros), "")
        page.provenance("bench_ros", None, "%s CPUs, load average %s at the end; %s" % (
            ros.get("cpus"), ros.get("load_average_end"), ros.get("date")))
        ros_table(page, gen_ros)

    text = "\n".join(page.lines).rstrip() + "\n"
    text = re.sub(r"\n{3,}", "\n\n", text)
    with open("BENCHMARKS.md", "w") as f:
        f.write(text)
    # Pictures: only of data that may be redistributed (the in-vivo frames are MIT-licensed; SCARED
    # is not redistributed).
    for key, name in (("invivo", "bench_invivo.png"), ("generated", "bench_generated.png")):
        src = os.path.join(a.out, key, "comparison.png")
        if os.path.exists(src):
            shutil.copyfile(src, os.path.join("docs", name))
    combined = {"date": date, "commit": page.commit, "commands": commands,
                "real": {"invivo": ev["invivo"], "real960_static": ev["real960_static"],
                         "real960_moving": ev["real960_moving"], "ground_truth": gt,
                         "invivo_1_thread": ev_t1["invivo"], "edge_tradeoff": tradeoff,
                         "real960_moving_1_thread": ev_t1["real960_moving"]},
                "generated": {"sequence": ev["generated"], "scenes": scenes},
                "ros": ros}
    text_json = json.dumps(combined, indent=1)
    # Per-frame series on one line each (one line per number would run to thousands of lines).
    text_json = re.sub(r"\[\s*([-0-9.eE+, \n]*?)\s*\]",
                       lambda m: "[" + re.sub(r"\s+", " ", m.group(1)).strip() + "]", text_json)
    with open("docs/benchmark_results.json", "w") as f:
        f.write(text_json + "\n")
    print("bench_report.py: BENCHMARKS.md (%d lines), docs/benchmark_results.json" % text.count("\n"))


if __name__ == "__main__":
    main()
