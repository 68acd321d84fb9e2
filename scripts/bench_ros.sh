#!/usr/bin/env bash
# Issue 5 benchmark: a 960x540 synthetic surgical bag played at 25 fps with `rosbag play` through
# endo_stereo's node and, in the same run on the same bag, through Debian's stereo_image_proc
# (SGBM). One after the other (not concurrently: on a small machine they would compete for the
# same cores), each as a standalone node (endo_stereo_node, /usr/lib/stereo_image_proc/...).
#
# Per node: pairs in, disparities out, output rate, drops (pairs in - outputs; endo_stereo also
# reports its own count), median and p90 latency from the left image's arrival at a listener to
# the disparity's arrival at the same listener (same stamp; transport included, both ways the
# same), density (valid disparity pixels).
#
# Writes out/bench_ros/ (bag, logs, JSON) and the table to $BENCH_NOTES (default
# out/bench_ros/ros_bench.md; BENCHMARKS.md section 6 records a run).
# Environment: BENCH_FRAMES (100), BENCH_WIDTH x BENCH_HEIGHT (960 x 540), BENCH_RATE (1.0 = 25 fps),
# BENCH_TARGETS ("endo_stereo stereo_image_proc"), BENCH_ES_PARAMS (endo_stereo's private
# parameters on top of config/default.yaml, "name=value ...", e.g. "backlog_pairs=1").
set -uo pipefail
source "$(dirname "$0")/env.sh"
es_source_ws

OUT="$ES_ROOT/out/bench_ros"
FRAMES="${BENCH_FRAMES:-100}"
WIDTH="${BENCH_WIDTH:-960}"
HEIGHT="${BENCH_HEIGHT:-540}"
RATE="${BENCH_RATE:-1.0}"
TARGETS="${BENCH_TARGETS:-endo_stereo stereo_image_proc}"
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

BAG="$OUT/bench_${WIDTH}x${HEIGHT}_${FRAMES}.bag"
if [ ! -s "$BAG" ]; then
  echo "[bench_ros] generating $BAG"
  "$WS/devel/lib/endo_stereo/endo_stereo_generate" --out "$OUT/sequence" --bag "$BAG" --no-images \
    --no-gt --frames "$FRAMES" --width "$WIDTH" --height "$HEIGHT" --namespace "$NS" \
    > "$OUT/log/generate.log" 2>&1 || { echo "[bench_ros] generation failed" >&2; exit 1; }
  # stereo_image_proc (image_geometry) aborts when the two camera_info frame_ids differ
  # (../shared/PLATFORM.md); the ROS stereo convention gives both the left optical frame. endo_stereo
  # accepts either, so both nodes get this same bag.
  /usr/bin/python3 - "$BAG" <<'PYEOF'
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
RANGE=$(( ( (DMAX - DMIN + 1 + 15) / 16 ) * 16 ))
DMAX=$(( DMIN + RANGE - 1 ))
echo "[bench_ros] disparity range $DMIN..$DMAX px ($RANGE values), $FRAMES frames ${WIDTH}x${HEIGHT} at $(/usr/bin/python3 -c "print(25*$RATE)") fps"

roscore -p "$PORT" > "$OUT/log/roscore.log" 2>&1 &
PIDS+=($!)
for _ in $(seq 100); do rosparam list > /dev/null 2>&1 && break; sleep 0.2; done

run_target() {  # $1 = endo_stereo | stereo_image_proc
  local target=$1 pid name
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
      > "$OUT/log/$target.log" 2>&1 &
  else
    name="$NS/stereo_image_proc"
    ROS_PACKAGE_PATH="$("$ES_ROOT/scripts/stereo_image_proc_env.sh" "$OUT/sip_pkgs")"
    export ROS_PACKAGE_PATH
    rosparam set "$name/stereo_algorithm" 1          # SGBM
    rosparam set "$name/min_disparity" "$DMIN"
    rosparam set "$name/disparity_range" "$RANGE"
    rosparam set "$name/correlation_window_size" 7   # SGBM block size (odd, 5..11 usual)
    /usr/lib/stereo_image_proc/stereo_image_proc __ns:="$NS" __name:=stereo_image_proc \
      > "$OUT/log/$target.log" 2>&1 &
  fi
  pid=$!
  PIDS+=($pid)
  sleep 3
  rm -f "$OUT/.done" "$OUT/.ready"
  /usr/bin/python3 "$ES_ROOT/scripts/demo_capture.py" listen --ns "$NS" --nodelet "$name" \
    --frames "$FRAMES" --out "$OUT/$target.json" --done-file "$OUT/.done" \
    --ready-file "$OUT/.ready" --timeout-s 600 2> "$OUT/log/listen_$target.err" &
  local lpid=$!
  PIDS+=($lpid)
  for _ in $(seq 100); do [ -e "$OUT/.ready" ] && break; sleep 0.1; done
  echo "[bench_ros] $target: playing"
  rosbag play -q --wait-for-subscribers -r "$RATE" "$BAG" > "$OUT/log/play_$target.log" 2>&1
  touch "$OUT/.done"
  wait "$lpid"
  kill "$pid" 2>/dev/null
  wait "$pid" 2>/dev/null
  rm -f "$OUT/.done" "$OUT/.ready"
}

for t in $TARGETS; do run_target "$t"; done

/usr/bin/python3 - "$OUT" "$NS" "$BENCH_NOTES" "$WIDTH" "$HEIGHT" "$FRAMES" "$RATE" "$DMIN" "$DMAX" $TARGETS <<'EOF'
import json, os, platform, subprocess, sys, time
out, ns, notes, w, h, frames, rate, dmin, dmax = sys.argv[1:10]
targets = sys.argv[10:]
def f(v, fmt="%.1f"):
    return "n/a" if v is None else fmt % v
cpu = subprocess.run("nproc", capture_output=True, text=True).stdout.strip()
load = open("/proc/loadavg").read().split()[:3]
pipeline_notes = []
rows = ["| node | pairs in | outputs | dropped | output rate (Hz) | latency median (ms) | latency p90 (ms) | density |",
        "|---|---|---|---|---|---|---|---|"]
for t in targets:
    p = os.path.join(out, t + ".json")
    if not os.path.exists(p):
        rows.append("| %s | (did not run) | | | | | | |" % t)
        continue
    r = json.load(open(p)).get(ns, {})
    diag = r.get("nodelet_diagnostics", {})
    dropped = r.get("dropped_or_lost")
    if diag.get("pipeline median (ms)") is not None:
        pipeline_notes.append("endo_stereo's own diagnostics: latency (pair complete -> published) "
                              "median %s ms, of which Pipeline::process median %s ms."
                              % (diag.get("latency median (ms)"), diag.get("pipeline median (ms)")))
    if diag.get("pairs dropped") is not None:
        dropped = "%s (nodelet: %s dropped, %s rejected)" % (dropped, diag.get("pairs dropped"),
                                                             diag.get("pairs rejected"))
    name = "endo_stereo (default preset)" if t == "endo_stereo" else "stereo_image_proc (SGBM, Debian)"
    rows.append("| %s | %s | %s | %s | %s | %s | %s | %s |" % (
        name, r.get("pairs_in"), r.get("outputs"), dropped,
        f(r.get("output_rate_over_input_span_hz")), f(r.get("latency_median_ms")),
        f(r.get("latency_p90_ms")), f(r.get("density_mean"), "%.3f")))
text = "\n".join([
    "# ROS benchmark (issue 5): endo_stereo vs stereo_image_proc on the same bag",
    "",
    "Measured %s by scripts/bench_ros.sh: a synthetic surgical bag (endo_stereo_generate), %s frames"
    " %sx%s, played with `rosbag play` at %s fps; disparity range %s..%s px for both; each node"
    " standalone, one after the other. Machine: %s cores, load average %s before the summary."
    % (time.strftime("%Y-%m-%d %H:%M"), frames, w, h, 25 * float(rate), dmin, dmax, cpu, " ".join(load)),
    "",
    *rows,
    "",
    "Latency: from the left image's arrival at a listener node to the arrival of the disparity"
    " with the same stamp at that listener. Output rate: disparities over the input's duration."
    " Dropped: input pairs without an output (endo_stereo counts the pairs pushed out of its"
    " backlog or skipped for a newer one; stereo_image_proc drops inside its synchronizer and"
    " queues).",
    *pipeline_notes,
    ""])
os.makedirs(os.path.dirname(notes), exist_ok=True)
open(notes, "w").write(text)
print(text)
print("[bench_ros] written to", notes)
EOF
