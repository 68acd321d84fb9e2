#!/usr/bin/env bash
# Long-run and overload tests of the endo_stereo node (RELIABILITY.md), with a private roscore.
#
# Usage: scripts/soak.sh [soak|overload] [extra driver arguments]
#   soak      (default) SOAK_FRAMES (100000) small pairs (320x240 bgr8 + camera_info) published as
#             fast as the node processes them, one at a time, while another thread hammers
#             dynamic_reconfigure with random valid and invalid values; the node's RSS is sampled
#             at start, after 500 frames, every 1000 frames and at the end. Fails if a frame is
#             lost beyond 1%, the node dies, or RSS grows more than 8 MB after warm-up.
#   overload  pairs published at OVERLOAD_RATE Hz (default 200) for OVERLOAD_S s (default 60),
#             faster than the node processes them: fails unless memory stays bounded, drops are
#             counted, every pair is accounted for, and the newest pair is processed.
# Environment: WS (workspace with endo_stereo built; default ./.ws), SOAK_OUT (results and logs,
# default out/reliability), SOAK_LABEL (file name prefix), SOAK_TIMEOUT_S (default 7200).
# The node runs with a small search range (matcher max_disparity 23, window_max_px 15) so that a
# 100000-pair run takes about an hour on two cores; memory behaviour does not depend on the range.
set -uo pipefail
source "$(dirname "$0")/env.sh"
source "$ES_ROOT/scripts/reliability_common.sh"
es_source_ws
mode="${1:-soak}"
[ $# -gt 0 ] && shift
out="${SOAK_OUT:-$ES_ROOT/out/reliability}"
label="${SOAK_LABEL:-$mode}"
mkdir -p "$out"
node_exe="$WS/devel/lib/endo_stereo/endo_stereo_node"
if [ ! -x "$node_exe" ]; then
  echo "[soak] $node_exe missing: build first (make build, or WS=... scripts/build.sh)" >&2
  exit 1
fi
export ROS_LOG_DIR="$out/ros_log_$label"
trap es_stop_master EXIT
es_start_master || exit 1
common=(--node-exe "$node_exe" --log-dir "$out/logs_$label" --out "$out/$label.json"
        --param matcher/max_disparity=23 --param matcher/window_max_px=15
        --param rectify/quality_stride=100)
case "$mode" in
  soak)
    args=(soak --frames "${SOAK_FRAMES:-100000}") ;;
  overload)
    args=(overload --rate "${OVERLOAD_RATE:-200}" --seconds "${OVERLOAD_S:-60}"
          --param queue_size=2) ;;
  *) echo "usage: $0 [soak|overload]" >&2; exit 2 ;;
esac
start=$(date +%s)
timeout "${SOAK_TIMEOUT_S:-7200}" /usr/bin/python3 "$ES_ROOT/scripts/reliability_driver.py" \
  "${args[@]}" "${common[@]}" "$@"
rc=$?
echo "[soak] $mode finished in $(( $(date +%s) - start )) s, exit $rc; result: $out/$label.json"
exit $rc
