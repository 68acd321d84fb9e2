#!/usr/bin/env bash
# The endo_stereo demo (README's first command, `make demo`; make has already installed the
# Debian packages and built the workspace). Headless, a few minutes:
#   1. generates a short synthetic surgical stereo bag (endo_stereo_generate: deforming tissue,
#      vessels, specular highlights, a moving instrument; exact ground truth),
#   2. plays it through the endo_stereo/reconstruction nodelet one pair at a time (every frame
#      processed): colourised disparity, coverage map, point cloud (PLY + pictures),
#   3. plays it again with `rosbag play` in real time (25 fps) to measure what a live feed gets:
#      frames in/out, output rate, drops, latency,
#   4. renders the cloud in rviz under Xvfb (when rviz is installed) and writes the figures,
#   5. when ../shared/data/real is present, runs real in-vivo footage (the 150 frames of
#      real/hamlyn_invivo1, search 0..127) through endo_stereo_evaluate: our disparity and coverage
#      beside OpenCV BM and SGBM (out/demo/invivo/comparison.png, disparity_*.png, coverage_*.png,
#      the table in figures.md); without the data it says so and skips this step,
#   6. with that data and rviz, plays the first 30 of those frames through a pass_through nodelet
#      (an assumed focal length and baseline: the frames come uncalibrated) and renders its RGB-D
#      output in rviz: the DepthCloud of depth/image_rect coloured by rgb/image_rect_color
#      (out/demo/rviz_invivo_depthcloud.png; the depth picture in out/demo/invivo_rgbd/).
# Outputs: out/demo/ (printed at the end).
#
# Environment: DEMO_FRAMES (default 30), DEMO_WIDTH x DEMO_HEIGHT (default 960 x 540, the paper's
# frame size), DEMO_SEED (1), DEMO_RVIZ (1 = try the rviz screenshot), WS (the workspace).
set -uo pipefail
source "$(dirname "$0")/env.sh"
es_source_ws
if [ ! -x "$WS/devel/lib/endo_stereo/endo_stereo_generate" ]; then
  echo "[demo] ERROR: the workspace $WS is not built (run: make build)" >&2
  exit 1
fi

OUT="$ES_ROOT/out/demo"
FRAMES="${DEMO_FRAMES:-30}"
WIDTH="${DEMO_WIDTH:-960}"
HEIGHT="${DEMO_HEIGHT:-540}"
SEED="${DEMO_SEED:-1}"
NS=/endoscope
rm -rf "$OUT"
mkdir -p "$OUT/log"
export ROS_LOG_DIR="$OUT/log/ros"
# A private master on a free port: the demo never talks to (or disturbs) a running ROS system.
PORT=$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("",0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://localhost:$PORT"
export ROS_HOSTNAME=localhost
export ROSCONSOLE_STDOUT_LINE_BUFFERED=1  # node logs reach out/demo/log/ as they happen
t_start=$(date +%s)

PIDS=()
cleanup() {
  for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done
  sleep 1
  for p in "${PIDS[@]}"; do kill -9 "$p" 2>/dev/null; done
}
trap cleanup EXIT

step() { echo "[demo] $(( $(date +%s) - t_start )) s: $*"; }

# --- 1. The bag ------------------------------------------------------------------------------
step "generating a ${WIDTH}x${HEIGHT} synthetic surgical bag, $FRAMES frames at 25 fps"
"$WS/devel/lib/endo_stereo/endo_stereo_generate" --out "$OUT/sequence" --bag "$OUT/synthetic.bag" \
  --no-images --frames "$FRAMES" --width "$WIDTH" --height "$HEIGHT" --seed "$SEED" \
  --namespace "$NS" > "$OUT/log/generate.log" 2>&1 || {
  echo "[demo] ERROR: endo_stereo_generate failed, see $OUT/log/generate.log" >&2; exit 1; }
read -r DMIN DMAX < <(/usr/bin/python3 - "$OUT/sequence/sequence.yaml" <<'EOF'
import sys, yaml
s = yaml.safe_load(open(sys.argv[1]))
print(s["min_disparity"], s["max_disparity"])
EOF
)
step "bag written ($(du -h "$OUT/synthetic.bag" | cut -f1)); disparity search range $DMIN..$DMAX px"

roscore -p "$PORT" > "$OUT/log/roscore.log" 2>&1 &
PIDS+=($!)
for _ in $(seq 100); do rosparam list > /dev/null 2>&1 && break; sleep 0.2; done

start_nodelet() {  # $1 = log name
  roslaunch "$ES_ROOT/launch/endo_stereo.launch" namespace:="${NS#/}" \
    min_disparity:="$DMIN" max_disparity:="$DMAX" > "$OUT/log/$1.log" 2>&1 &
  NODELET_PID=$!
  PIDS+=($NODELET_PID)
  local deadline=$(( $(date +%s) + 60 ))
  while [ "$(date +%s)" -lt "$deadline" ]; do
    grep -q "FATAL" "$OUT/log/$1.log" 2>/dev/null && break
    # The reconfigure server is the last thing the nodelet starts.
    rostopic list 2>/dev/null | grep -q "^$NS/reconstruction/parameter_updates\$" && return 0
    sleep 0.5
  done
  echo "[demo] ERROR: the nodelet did not start, see $OUT/log/$1.log" >&2
  return 1
}

XVFB_DISP=""
rviz_shot() {  # $1 = rviz config, $2 = namespace, $3 = PNG, $4 = log name; Xvfb on first use
  if [ -z "$XVFB_DISP" ]; then
    XVFB_DISP=":$(( 90 + RANDOM % 100 ))"
    Xvfb "$XVFB_DISP" -screen 0 1280x800x24 > "$OUT/log/xvfb.log" 2>&1 &
    PIDS+=($!)
    sleep 2
  fi
  DISPLAY="$XVFB_DISP" LIBGL_ALWAYS_SOFTWARE=1 ROS_NAMESPACE="$2" \
    rviz -d "$1" > "$OUT/log/$4.log" 2>&1 &
  local rviz_pid=$!
  PIDS+=($rviz_pid)
  sleep "${DEMO_RVIZ_WAIT_S:-20}"
  local rc=1
  if kill -0 "$rviz_pid" 2>/dev/null && \
     DISPLAY="$XVFB_DISP" import -window root "$3" 2>> "$OUT/log/$4.log"; then
    rc=0
  fi
  kill "$rviz_pid" 2>/dev/null
  wait "$rviz_pid" 2>/dev/null
  return $rc
}

# --- 2. Every frame through the nodelet ------------------------------------------------------
start_nodelet nodelet_paced || exit 1
step "nodelet up; playing the pairs one at a time (every frame processed)"
HOLD=0
if [ "${DEMO_RVIZ:-1}" = 1 ] && command -v rviz > /dev/null && command -v Xvfb > /dev/null; then
  HOLD=90
fi
/usr/bin/python3 "$ES_ROOT/scripts/demo_capture.py" paced --bag "$OUT/synthetic.bag" --ns "$NS" \
  --out "$OUT" --hold-s "$HOLD" 2> "$OUT/log/paced.err" &
CAPTURE_PID=$!
PIDS+=($CAPTURE_PID)

# --- 4 (while the last outputs are held). rviz screenshot --------------------------------------
if [ "$HOLD" -gt 0 ]; then
  for _ in $(seq 3000); do
    [ -e "$OUT/.view_ready" ] && break
    kill -0 "$CAPTURE_PID" 2>/dev/null || break
    sleep 0.2
  done
  if [ -e "$OUT/.view_ready" ]; then
    step "rendering the cloud in rviz (Xvfb, software GL)"
    # The demo's view: the same displays as rviz/endo_stereo.rviz, in the /demo_view namespace
    # where the capture holds the last outputs.
    if rviz_shot "$ES_ROOT/rviz/endo_stereo.rviz" /demo_view "$OUT/rviz.png" rviz; then
      step "rviz screenshot written"
    else
      echo "[demo] rviz screenshot failed (see $OUT/log/rviz.log); cloud.png is the software render"
    fi
    touch "$OUT/.view_done"
  fi
fi
wait "$CAPTURE_PID"
rc=$?
rm -f "$OUT/.view_ready" "$OUT/.view_done"
if [ $rc -ne 0 ] || [ ! -s "$OUT/paced.json" ]; then
  echo "[demo] ERROR: the paced playback failed, see $OUT/log/paced.err" >&2
  exit 1
fi
kill "$NODELET_PID" 2>/dev/null
wait "$NODELET_PID" 2>/dev/null

# --- 3. Real time with rosbag play -------------------------------------------------------------
start_nodelet nodelet_realtime || exit 1
step "playing the bag with rosbag play at 25 fps (what a live feed gets)"
rm -f "$OUT/.play_done"
/usr/bin/python3 "$ES_ROOT/scripts/demo_capture.py" listen --ns "$NS" \
  --nodelet "$NS/reconstruction" --frames "$FRAMES" --out "$OUT/realtime.json" \
  --done-file "$OUT/.play_done" --ready-file "$OUT/.listen_ready" --timeout-s 300 \
  2> "$OUT/log/listen.err" &
LISTEN_PID=$!
PIDS+=($LISTEN_PID)
for _ in $(seq 100); do [ -e "$OUT/.listen_ready" ] && break; sleep 0.1; done
rosbag play -q --wait-for-subscribers "$OUT/synthetic.bag" > "$OUT/log/rosbag_play.log" 2>&1
touch "$OUT/.play_done"
wait "$LISTEN_PID"
rm -f "$OUT/.play_done" "$OUT/.listen_ready"

# --- Figures -----------------------------------------------------------------------------------
/usr/bin/python3 - "$OUT" "$NS" <<'EOF'
import json, os, sys
out, ns = sys.argv[1], sys.argv[2]
p = json.load(open(os.path.join(out, "paced.json")))
r = json.load(open(os.path.join(out, "realtime.json"))).get(ns, {})
diag = r.get("nodelet_diagnostics", {})
def f(v, fmt="%.1f"):
    return "n/a" if v is None else fmt % v
lines = [
    "# endo_stereo demo figures",
    "",
    "Synthetic surgical stereo bag: %d frames, %dx%d, 25 fps." % (p["frames"], p["width"], p["height"]),
    "",
    "## Every frame through the nodelet (paced playback)",
    "| figure | value |", "|---|---|",
    "| frames in / out | %d / %d |" % (p["frames"], p["processed"]),
    "| latency per frame, median / p90 (publish -> disparity received) | %s / %s ms |"
    % (f(p.get("latency_median_ms")), f(p.get("latency_p90_ms"))),
    "| processing rate (1 / median latency) | %s fps |" % f(p.get("processing_fps")),
    "| density (valid pixels), mean / last frame | %s / %s |"
    % (f(p.get("density_mean"), "%.3f"), f(p.get("density_last"), "%.3f")),
    "| coverage: central pixels updated within %s frames | %s |"
    % (p.get("coverage_within_frames", "n/a"), f(p.get("coverage_central_share"), "%.3f")),
    "| coverage: all pixels updated within %s frames | %s |"
    % (p.get("coverage_within_frames", "n/a"), f(p.get("coverage_overall_share"), "%.3f")),
    "| cloud: valid points, depth median (5-95%%) | %s, %s m (%s-%s) |"
    % (p.get("cloud_points", "n/a"), f(p.get("cloud_depth_median_m"), "%.4f"),
       f(p.get("cloud_depth_p5_m"), "%.4f"), f(p.get("cloud_depth_p95_m"), "%.4f")),
    "",
    "## Real time: rosbag play at 25 fps",
    "| figure | value |", "|---|---|",
    "| pairs in / disparities out | %s / %s |" % (r.get("pairs_in"), r.get("outputs")),
    "| dropped (pushed out of the backlog or skipped for a newer pair), from the nodelet's diagnostics | %s |" % diag.get("pairs dropped", "n/a"),
    "| rejected | %s |" % diag.get("pairs rejected", "n/a"),
    "| output rate over the input's duration | %s Hz |" % f(r.get("output_rate_over_input_span_hz")),
    "| latency median / p90 (left image received -> disparity received) | %s / %s ms |"
    % (f(r.get("latency_median_ms")), f(r.get("latency_p90_ms"))),
    "| density mean | %s |" % f(r.get("density_mean"), "%.3f"),
]
open(os.path.join(out, "figures.md"), "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
EOF

# --- 5. Real footage ----------------------------------------------------------------------------
REAL="$(cd "$ES_ROOT/.." && pwd)/shared/data/real/hamlyn_invivo1"
if [ -e "$REAL/left/0001.png" ]; then
  step "real in-vivo footage: 150 frames of $REAL (ours with and without priors, OpenCV BM and SGBM)"
  if "$WS/devel/lib/endo_stereo/endo_stereo_evaluate" --left "$REAL/left/%04d.png" \
      --right "$REAL/right/%04d.png" --min-disparity 0 --max-disparity 127 \
      --label "real in-vivo video (hamlyn_invivo1)" --quiet --out "$OUT/invivo" \
      > "$OUT/invivo.md" 2> "$OUT/log/invivo.err"; then
    { echo; echo "## Real in-vivo footage (endo_stereo_evaluate)"; cat "$OUT/invivo.md"; } >> "$OUT/figures.md"
    cat "$OUT/invivo.md"
  else
    echo "[demo] ERROR: endo_stereo_evaluate failed on the in-vivo frames, see $OUT/log/invivo.err" >&2
  fi
  # --- 6. The RGB-D output on the real frames, as rviz's DepthCloud shows it ---------------------
  if [ "${DEMO_RVIZ:-1}" = 1 ] && command -v rviz > /dev/null && command -v Xvfb > /dev/null; then
    INV_NS=/invivo
    INV_OUT="$OUT/invivo_rgbd"
    mkdir -p "$INV_OUT"
    roslaunch "$ES_ROOT/launch/endo_stereo.launch" namespace:="${INV_NS#/}" \
      rectify_mode:=pass_through min_disparity:=0 max_disparity:=127 \
      > "$OUT/log/nodelet_invivo.log" 2>&1 &
    INV_NODELET_PID=$!
    PIDS+=($INV_NODELET_PID)
    step "in-vivo RGB-D: 30 frames through a pass_through nodelet (assumed f 400 px, baseline 5 mm)"
    /usr/bin/python3 "$ES_ROOT/scripts/demo_capture.py" invivo --frames-dir "$REAL" \
      --ns "$INV_NS" --out "$INV_OUT" --count 30 --focal-px 400 --baseline-m 0.005 \
      --hold-s 90 2> "$OUT/log/invivo_rgbd.err" &
    INV_PID=$!
    PIDS+=($INV_PID)
    for _ in $(seq 3000); do
      [ -e "$INV_OUT/.view_ready" ] && break
      kill -0 "$INV_PID" 2>/dev/null || break
      sleep 0.2
    done
    if [ -e "$INV_OUT/.view_ready" ] && /usr/bin/python3 "$ES_ROOT/scripts/demo_depthcloud_view.py" \
         "$ES_ROOT/rviz/endo_stereo.rviz" "$INV_OUT/invivo_rgbd.json" "$INV_OUT/depthcloud.rviz" \
         2>> "$OUT/log/invivo_rgbd.err"; then
      step "rendering the in-vivo DepthCloud in rviz (Xvfb, software GL)"
      if rviz_shot "$INV_OUT/depthcloud.rviz" /demo_invivo_view \
           "$OUT/rviz_invivo_depthcloud.png" rviz_invivo; then
        step "rviz DepthCloud screenshot written"
      else
        echo "[demo] rviz DepthCloud screenshot failed (see $OUT/log/rviz_invivo.log)"
      fi
    else
      echo "[demo] ERROR: no RGB-D output on the in-vivo frames, see $OUT/log/invivo_rgbd.err" >&2
    fi
    touch "$INV_OUT/.view_done"
    wait "$INV_PID"
    rm -f "$INV_OUT/.view_ready" "$INV_OUT/.view_done"
    kill "$INV_NODELET_PID" 2>/dev/null
    wait "$INV_NODELET_PID" 2>/dev/null
    if [ -s "$INV_OUT/figures.md" ]; then
      { echo; cat "$INV_OUT/figures.md"; } >> "$OUT/figures.md"
      cat "$INV_OUT/figures.md"
    fi
  fi
else
  echo "[demo] NOTE: the real in-vivo frames are absent ($REAL): the demo shows generated frames only."
  echo "[demo]       Put the evaluation data beside the repository as ../shared/data to see real footage."
fi

step "done"
echo
echo "[demo] outputs in $OUT:"
for f in disparity_color.png coverage.png cloud.png rviz.png left_rect.png cloud.ply figures.md \
         paced.json realtime.json synthetic.bag invivo/comparison.png \
         invivo/disparity_ours.png invivo/coverage_ours.png rviz_invivo_depthcloud.png \
         invivo_rgbd/depth.png; do
  [ -e "$OUT/$f" ] && printf '  %-20s %s\n' "$f" "$(du -h "$OUT/$f" | cut -f1)"
done
echo "[demo] replay it in rviz: roslaunch $ES_ROOT/launch/playback.launch bag:=$OUT/synthetic.bag rviz:=true min_disparity:=$DMIN max_disparity:=$DMAX"
