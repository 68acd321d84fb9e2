#!/usr/bin/env bash
# The nodelet on a stream: bags played at 25 fps with `rosbag play` through endo_stereo's node and,
# on the same bag, through Debian's stereo_image_proc (SGBM). One after the other (not
# concurrently: on a small machine they would compete for the same cores), each as a standalone
# node (endo_stereo_node, /usr/lib/stereo_image_proc/...), started afresh for each play. Each
# bag is played BENCH_ROS_RUNS times (default 3) through each node, the nodes taking turns
# (run 1 of every node, then run 2, ...), and every run is reported.
#
# Cases (BENCH_CASES, default "invivo real960 synthetic"; the real ones only when
# ../shared/data/real is present):
#   invivo     all 150 frames of real/hamlyn_invivo1 (360x288, rectified), search 0..127
#   real960    the SCARED ds1 pair rectified with its calibration (endo_stereo_cli --calib), a
#              960x540 crop window moving on a circle of radius 24 px, one turn every 75 frames
#              (as endo_stereo_evaluate --pan), BENCH_REAL_FRAMES frames (100), search 48..111
#   synthetic  a generated surgical bag (endo_stereo_generate), BENCH_WIDTH x BENCH_HEIGHT
#              (960 x 540), BENCH_FRAMES frames (100), its suggested range rounded to 16
# Real frames become bags with scripts/frames_to_bag.py (rectified camera_info: no distortion,
# R = I; f and the baseline only scale depth).
#
# Per node: pairs in, disparities out, output rate, drops (pairs in - outputs; endo_stereo also
# reports its own count), median and p90 latency from the left image's arrival at a listener to
# the disparity's arrival at the same listener (same stamp; transport included, both ways the
# same), density (valid disparity pixels).
#
# Writes out/bench_ros/ (bags, logs, the listener's JSON of every run: CASE_TARGET_runK.json,
# ros_bench.json with one entry per run) and the table to $BENCH_NOTES (default
# out/bench_ros/ros_bench.md: one row per case and node, each cell run 1 / run 2 / ...);
# scripts/bench_report.py puts it in BENCHMARKS.md.
# Environment: BENCH_CASES, BENCH_FRAMES, BENCH_REAL_FRAMES, BENCH_WIDTH, BENCH_HEIGHT,
# BENCH_RATE (1.0 = 25 fps), BENCH_TARGETS ("endo_stereo stereo_image_proc"), BENCH_ROS_RUNS
# (plays per case and node, default 3), BENCH_ES_PARAMS (endo_stereo's private parameters on
# top of config/default.yaml, "name=value ...").
set -uo pipefail
source "$(dirname "$0")/env.sh"
es_source_ws

OUT="$ES_ROOT/out/bench_ros"
FRAMES="${BENCH_FRAMES:-100}"
REAL_FRAMES="${BENCH_REAL_FRAMES:-100}"
WIDTH="${BENCH_WIDTH:-960}"
HEIGHT="${BENCH_HEIGHT:-540}"
RATE="${BENCH_RATE:-1.0}"
TARGETS="${BENCH_TARGETS:-endo_stereo stereo_image_proc}"
RUNS="${BENCH_ROS_RUNS:-3}"
if ! [[ "$RUNS" =~ ^[1-9][0-9]*$ ]]; then
  echo "[bench_ros] BENCH_ROS_RUNS must be a positive integer, got '$RUNS'" >&2
  exit 2
fi
REAL="$(cd "$ES_ROOT/.." && pwd)/shared/data/real"
if [ -d "$REAL" ]; then
  CASES="${BENCH_CASES:-invivo real960 synthetic}"
else
  echo "[bench_ros] NOTE: $REAL is absent: the real-frame cases are skipped" >&2
  CASES="${BENCH_CASES:-synthetic}"
fi
if [ -z "${BENCH_NOTES:-}" ]; then
  BENCH_NOTES="$OUT/ros_bench.md"
fi
NS=/endoscope
mkdir -p "$OUT/log"
export ROS_LOG_DIR="$OUT/log/ros"
PORT=$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("",0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://localhost:$PORT"
export ROS_HOSTNAME=localhost
export ROSCONSOLE_STDOUT_LINE_BUFFERED=1

PIDS=()
cleanup() {
  for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done
  sleep 1
  for p in "${PIDS[@]}"; do kill -9 "$p" 2>/dev/null; done
}
trap cleanup EXIT

# prepare_case CASE: builds the case's bag if missing; sets BAG, DMIN, DMAX, NFRAMES, DESC.
prepare_case() {
  case "$1" in
  synthetic)
    NFRAMES="$FRAMES"
    BAG="$OUT/bench_${WIDTH}x${HEIGHT}_${FRAMES}.bag"
    DESC="generated surgical scene (endo_stereo_generate), ${WIDTH}x${HEIGHT}"
    if [ ! -s "$BAG" ]; then
      echo "[bench_ros] generating $BAG"
      "$WS/devel/lib/endo_stereo/endo_stereo_generate" --out "$OUT/sequence" --bag "$BAG" \
        --no-images --no-gt --frames "$FRAMES" --width "$WIDTH" --height "$HEIGHT" \
        --namespace "$NS" > "$OUT/log/generate.log" 2>&1 || return 1
      # stereo_image_proc (image_geometry) aborts when the two camera_info frame_ids differ; the
      # ROS stereo convention gives both the left optical frame. endo_stereo accepts either, so
      # both nodes get this same bag.
      /usr/bin/python3 - "$BAG" <<'PYEOF' || return 1
import os, sys, rosbag
src = sys.argv[1]
tmp = src + ".tmp"
left_frame = None
with rosbag.Bag(src) as bag:
    for topic, msg, t in bag.read_messages():
        if topic.endswith("/left/camera_info"):
            left_frame = msg.header.frame_id
            break
with rosbag.Bag(src) as bag, rosbag.Bag(tmp, "w") as out:
    for topic, msg, t in bag.read_messages():
        if topic.endswith("/right/camera_info"):
            msg.header.frame_id = left_frame
        out.write(topic, msg, t)
os.replace(tmp, src)
PYEOF
    fi
    read -r DMIN DMAX < <(/usr/bin/python3 -c "import yaml,sys; s=yaml.safe_load(open(sys.argv[1])); print(s['min_disparity'], s['max_disparity'])" "$OUT/sequence/sequence.yaml")
    # SGBM needs a range that is a multiple of 16; both search the same span.
    local range=$(( ( (DMAX - DMIN + 1 + 15) / 16 ) * 16 ))
    DMAX=$(( DMIN + range - 1 ))
    ;;
  invivo)
    NFRAMES=150
    DMIN=0
    DMAX=127
    BAG="$OUT/invivo_hamlyn1_150.bag"
    DESC="real in-vivo video (hamlyn_invivo1), 360x288"
    if [ ! -s "$BAG" ]; then
      /usr/bin/python3 "$ES_ROOT/scripts/frames_to_bag.py" \
        --left "$REAL/hamlyn_invivo1/left/%04d.png" --right "$REAL/hamlyn_invivo1/right/%04d.png" \
        --first 1 --count 150 --ns "$NS" --out "$BAG" > "$OUT/log/bag_invivo.log" 2>&1 || return 1
    fi
    ;;
  real960)
    NFRAMES="$REAL_FRAMES"
    DMIN=48
    DMAX=111
    BAG="$OUT/real960_scared_pan_${REAL_FRAMES}.bag"
    DESC="real 960x540 frame (SCARED ds1 rectified, moving crop)"
    if [ ! -s "$BAG" ]; then
      local rect="$OUT/scared_rect"
      if [ ! -s "${rect}_left.png" ]; then
        "$WS/devel/lib/endo_stereo/endo_stereo_cli" --left "$REAL/scared_ds1_pair/Left_Image.png" \
          --right "$REAL/scared_ds1_pair/Right_Image.png" \
          --calib "$REAL/scared_ds1_pair/calib_scared_official_ds1-3.yaml" \
          --out-rectified "$rect" --min-disparity 48 --max-disparity 111 --quiet \
          > "$OUT/log/rectify_scared.log" 2>&1 || return 1
      fi
      /usr/bin/python3 "$ES_ROOT/scripts/frames_to_bag.py" --left "${rect}_left.png" \
        --right "${rect}_right.png" --crop 960x540 --pan "$REAL_FRAMES" --ns "$NS" \
        --out "$BAG" > "$OUT/log/bag_real960.log" 2>&1 || return 1
    fi
    ;;
  *)
    echo "[bench_ros] unknown case $1" >&2
    return 1
    ;;
  esac
  echo "[bench_ros] $1: $DESC, $NFRAMES frames at $(/usr/bin/python3 -c "print(25*$RATE)") fps, disparity range $DMIN..$DMAX px"
}

roscore -p "$PORT" > "$OUT/log/roscore.log" 2>&1 &
PIDS+=($!)
for _ in $(seq 100); do rosparam list > /dev/null 2>&1 && break; sleep 0.2; done

run_target() {  # $1 = endo_stereo | stereo_image_proc, $2 = case, $3 = run (1, 2, ...)
  local target=$1 case_name=$2 run=$3 pid name
  local id="${case_name}_${target}_run${run}"
  rosparam delete "$NS" > /dev/null 2>&1 || true
  if [ "$target" = endo_stereo ]; then
    name="$NS/endo_stereo"
    rosparam load "$ES_ROOT/config/default.yaml" "$name"
    rosparam set "$name/matcher/min_disparity" "$DMIN"
    rosparam set "$name/matcher/max_disparity" "$DMAX"
    for kv in ${BENCH_ES_PARAMS:-}; do  # e.g. "backlog_pairs=1 rectify/quality_stride=0"
      rosparam set "$name/${kv%%=*}" "${kv#*=}"
    done
    "$WS/devel/lib/endo_stereo/endo_stereo_node" __ns:="$NS" __name:=endo_stereo \
      > "$OUT/log/$id.log" 2>&1 &
  else
    name="$NS/stereo_image_proc"
    ROS_PACKAGE_PATH="$("$ES_ROOT/scripts/stereo_image_proc_env.sh" "$OUT/sip_pkgs")"
    export ROS_PACKAGE_PATH
    rosparam set "$name/stereo_algorithm" 1          # SGBM
    rosparam set "$name/min_disparity" "$DMIN"
    rosparam set "$name/disparity_range" "$(( DMAX - DMIN + 1 ))"
    rosparam set "$name/correlation_window_size" 7   # SGBM block size (odd, 5..11 usual)
    /usr/lib/stereo_image_proc/stereo_image_proc __ns:="$NS" __name:=stereo_image_proc \
      > "$OUT/log/$id.log" 2>&1 &
  fi
  pid=$!
  PIDS+=($pid)
  sleep 3
  rm -f "$OUT/.done" "$OUT/.ready"
  /usr/bin/python3 "$ES_ROOT/scripts/demo_capture.py" listen --ns "$NS" --nodelet "$name" \
    --frames "$NFRAMES" --out "$OUT/$id.json" --done-file "$OUT/.done" \
    --ready-file "$OUT/.ready" --timeout-s 600 2> "$OUT/log/listen_$id.err" &
  local lpid=$!
  PIDS+=($lpid)
  for _ in $(seq 100); do [ -e "$OUT/.ready" ] && break; sleep 0.1; done
  echo "[bench_ros] $case_name / $target: playing (run $run of $RUNS)"
  rosbag play -q --wait-for-subscribers -r "$RATE" "$BAG" \
    > "$OUT/log/play_$id.log" 2>&1
  touch "$OUT/.done"
  wait "$lpid"
  kill "$pid" 2>/dev/null
  wait "$pid" 2>/dev/null
  rm -f "$OUT/.done" "$OUT/.ready"
}

CASE_LINES=()
for c in $CASES; do
  if ! prepare_case "$c"; then
    echo "[bench_ros] $c: the bag could not be prepared (see $OUT/log/)" >&2
    continue
  fi
  for t in $TARGETS; do
    rm -f "$OUT/${c}_$t.json" "$OUT/${c}_${t}"_run*.json
  done
  for run in $(seq "$RUNS"); do
    for t in $TARGETS; do
      run_target "$t" "$c" "$run"
    done
  done
  CASE_LINES+=("$c|$DESC|$NFRAMES|$DMIN|$DMAX")
done

/usr/bin/python3 - "$OUT" "$NS" "$BENCH_NOTES" "$RATE" "$TARGETS" "$RUNS" "${CASE_LINES[@]}" <<'PYEOF'
import json, os, subprocess, sys, time
out, ns, notes, rate, targets, runs = sys.argv[1:7]
targets = targets.split()
runs = int(runs)
cases = [c.split("|") for c in sys.argv[7:]]
def f(v, fmt="%.1f"):
    return "n/a" if v is None else fmt % v
cpu = subprocess.run("nproc", capture_output=True, text=True).stdout.strip()
load = open("/proc/loadavg").read().split()[:3]
rows = ["| stream | node | pairs in | outputs | dropped | output rate (Hz) | latency median (ms) | latency p90 (ms) | density |",
        "|---|---|---:|---:|---|---:|---:|---:|---:|"]
results = []  # one entry per run
notes_lines = []
for name, desc, nframes, dmin, dmax in cases:
    for t in targets:
        node = "endo_stereo (default preset)" if t == "endo_stereo" else "stereo_image_proc (SGBM, Debian)"
        stream = "%s, %s frames, %s..%s" % (desc, nframes, dmin, dmax)
        row = []  # per run: its entry, or None when its JSON is missing
        for k in range(1, runs + 1):
            p = os.path.join(out, "%s_%s_run%d.json" % (name, t, k))
            if not os.path.exists(p):
                row.append(None)
                continue
            r = json.load(open(p)).get(ns, {})
            diag = r.get("nodelet_diagnostics", {})
            entry = {"case": name, "description": desc, "frames": int(nframes),
                     "min_disparity": int(dmin), "max_disparity": int(dmax), "node": t,
                     "run": k, "json": os.path.basename(p),
                     "pairs_in": r.get("pairs_in"), "outputs": r.get("outputs"),
                     "dropped_or_lost": r.get("dropped_or_lost"),
                     "nodelet_pairs_dropped": diag.get("pairs dropped"),
                     "nodelet_pairs_rejected": diag.get("pairs rejected"),
                     "output_rate_hz": r.get("output_rate_over_input_span_hz"),
                     "latency_median_ms": r.get("latency_median_ms"),
                     "latency_p90_ms": r.get("latency_p90_ms"),
                     "density_mean": r.get("density_mean"),
                     "nodelet_latency_median_ms": diag.get("latency median (ms)"),
                     "pipeline_median_ms": diag.get("pipeline median (ms)")}
            results.append(entry)
            row.append(entry)
        if not any(row):
            rows.append("| %s | %s | (did not run) | | | | | | |" % (stream, node))
            continue

        def col(key, fmt="%s"):  # run 1 / run 2 / ...; "-" for a run without a result
            return " / ".join("-" if e is None else f(e.get(key), fmt) for e in row)
        dropped = col("dropped_or_lost")
        if any(e and e.get("nodelet_pairs_dropped") is not None for e in row):
            dropped += " (nodelet: %s dropped, %s rejected)" % (col("nodelet_pairs_dropped"),
                                                                col("nodelet_pairs_rejected"))
        if any(e and e.get("pipeline_median_ms") is not None for e in row):
            notes_lines.append("%s: endo_stereo's own diagnostics: latency (pair complete -> "
                               "published) median %s ms, of which Pipeline::process median %s ms."
                               % (desc, col("nodelet_latency_median_ms"),
                                  col("pipeline_median_ms")))
        rows.append("| %s | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            stream, node, col("pairs_in"), col("outputs"), dropped, col("output_rate_hz", "%.1f"),
            col("latency_median_ms", "%.1f"), col("latency_p90_ms", "%.1f"),
            col("density_mean", "%.3f")))
stamp = time.strftime("%Y-%m-%d %H:%M %Z")
text = "\n".join([
    "# The nodelet against stereo_image_proc on the same bags",
    "",
    "Measured %s by scripts/bench_ros.sh: each bag played with `rosbag play` at %g fps, %d times"
    " through each node (each cell: run 1 / run 2 / ...); the same disparity range for both"
    " nodes; each node standalone, one after the other. Machine: %s cores, load average %s at"
    " the end." % (stamp, 25 * float(rate), runs, cpu, " ".join(load)),
    "",
    *rows,
    "",
    "Latency: from the left image's arrival at a listener node to the arrival of the disparity"
    " with the same stamp at that listener. Output rate: disparities over the input's duration."
    " Dropped: input pairs without an output (endo_stereo counts the pairs pushed out of its"
    " backlog or skipped for a newer one; stereo_image_proc drops inside its synchronizer and"
    " queues).",
    *notes_lines,
    ""])
os.makedirs(os.path.dirname(notes), exist_ok=True)
open(notes, "w").write(text)
with open(os.path.join(out, "ros_bench.json"), "w") as fh:
    json.dump({"date": stamp, "rate_fps": 25 * float(rate), "cpus": cpu, "runs_per_node": runs,
               "load_average_end": " ".join(load), "runs": results}, fh, indent=2)
print(text)
print("[bench_ros] written to", notes, "and", os.path.join(out, "ros_bench.json"))
PYEOF
