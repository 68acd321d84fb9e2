#!/usr/bin/env bash
# The bad-input inventory of RELIABILITY.md at the ROS level: every bad input, each followed by a
# good pair, against endo_stereo's node and against Debian's stereo_image_proc, side by side.
#
# Usage: scripts/inventory.sh [endo_stereo|stereo_image_proc|both]   (default both)
# Results: $INVENTORY_OUT (default out/reliability)/inventory_<target>.json and the node logs.
# Needs WS with endo_stereo built; stereo_image_proc is made loadable with
# scripts/stereo_image_proc_env.sh (plugin descriptions in a scratch folder).
set -uo pipefail
source "$(dirname "$0")/env.sh"
source "$ES_ROOT/scripts/reliability_common.sh"
es_source_ws
which="${1:-both}"
out="${INVENTORY_OUT:-$ES_ROOT/out/reliability}"
mkdir -p "$out"
export ROS_LOG_DIR="$out/ros_log_inventory"
trap es_stop_master EXIT
rc=0
for target in endo_stereo stereo_image_proc; do
  [ "$which" = both ] || [ "$which" = "$target" ] || continue
  es_start_master || exit 1
  if [ "$target" = stereo_image_proc ]; then
    ROS_PACKAGE_PATH="$("$ES_ROOT/scripts/stereo_image_proc_env.sh" "$out/sip_pkgs")"
    export ROS_PACKAGE_PATH
  fi
  /usr/bin/python3 "$ES_ROOT/scripts/reliability_driver.py" inventory --target "$target" \
    --node-exe "$WS/devel/lib/endo_stereo/endo_stereo_node" --log-dir "$out/logs_inventory" \
    --out "$out/inventory_$target.json" || rc=1
  es_stop_master
done
exit $rc
