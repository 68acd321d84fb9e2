#!/usr/bin/env bash
# Makes Debian's stereo_image_proc (and image_proc) nodelets loadable, for running the peer next to
# endo_stereo (benchmarks, the bad-input inventory of RELIABILITY.md).
#
# Debian packages the libraries (libstereo_image_proc.so.0d, libimage_proc.so.0d) and the node
# /usr/lib/stereo_image_proc/stereo_image_proc, but not the plugin descriptions, so pluginlib cannot
# find the nodelets. This writes, under DIR, one scratch package per library:
#   DIR/stereo_image_proc/{package.xml, nodelet_plugins.xml, lib/libstereo_image_proc.so -> Debian's}
#   DIR/image_proc/{package.xml, nodelet_plugins.xml, lib/libimage_proc.so -> Debian's}
# and prints the ROS_PACKAGE_PATH to use (DIR first, then the current value), nothing else on stdout.
#
# Usage:
#   export ROS_PACKAGE_PATH="$(scripts/stereo_image_proc_env.sh /tmp/sip_pkgs)"
#   /usr/lib/stereo_image_proc/stereo_image_proc __ns:=stereo      # the Debian node, or
#   rosrun nodelet nodelet load stereo_image_proc/disparity MANAGER ...
#   scripts/stereo_image_proc_env.sh --exec COMMAND [ARGS]  # COMMAND run with that path (DIR is
#       ${TMPDIR:-/tmp}/endo_stereo_sip_pkgs_<uid>); a launch file's launch-prefix, so that a
#       nodelet manager can load stereo_image_proc's nodelets (test/ros/stereo_image_proc.test)
# Idempotent: running it again rewrites the same files.
set -euo pipefail
exec_mode=0
if [ "${1:-}" = "--exec" ]; then
  exec_mode=1
  shift
  [ $# -gt 0 ] || { echo "usage: $0 --exec COMMAND [ARGS]" >&2; exit 2; }
  dir="${TMPDIR:-/tmp}/endo_stereo_sip_pkgs_$(id -u)"
else
  dir="${1:?usage: $0 DIR (scratch folder for the plugin descriptions) | --exec COMMAND [ARGS]}"
fi
mkdir -p "$dir"
dir="$(cd "$dir" && pwd)"

find_lib() {
  local name="$1" p
  for p in /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/lib; do
    if [ -e "$p/$name.so.0d" ]; then echo "$p/$name.so.0d"; return 0; fi
  done
  p=$(ldconfig -p 2>/dev/null | grep -oE "/[^ ]*/$name\.so[^ ]*" | head -n 1 || true)
  [ -n "$p" ] && { echo "$p"; return 0; }
  echo "[stereo_image_proc_env] ERROR: $name not found (apt-get install ros-stereo-image-proc)" >&2
  return 1
}

# write_package NAME LIBRARY "lookup_name:Class:description" ...
write_package() {
  local pkg="$1" lib="$2"
  shift 2
  local target
  target=$(find_lib "$lib")
  mkdir -p "$dir/$pkg/lib"
  ln -sfn "$target" "$dir/$pkg/lib/$lib.so"
  cat > "$dir/$pkg/package.xml" <<EOF
<?xml version="1.0"?>
<package format="2">
  <name>$pkg</name>
  <version>1.17.0</version>
  <description>Plugin description for Debian's $lib (scratch, written by endo_stereo's
    scripts/stereo_image_proc_env.sh).</description>
  <maintainer email="nobody@example.com">nobody</maintainer>
  <license>BSD</license>
  <buildtool_depend>catkin</buildtool_depend>
  <exec_depend>nodelet</exec_depend>
  <export>
    <nodelet plugin="\${prefix}/nodelet_plugins.xml"/>
  </export>
</package>
EOF
  {
    echo "<library path=\"lib/$lib\">"
    local spec name cls
    for spec in "$@"; do
      name="${spec%%:*}"
      cls="${spec#*:}"
      echo "  <class name=\"$name\" type=\"$cls\" base_class_type=\"nodelet::Nodelet\">"
      echo "    <description>$name (Debian build)</description>"
      echo "  </class>"
    done
    echo "</library>"
  } > "$dir/$pkg/nodelet_plugins.xml"
}

write_package stereo_image_proc libstereo_image_proc \
  "stereo_image_proc/disparity:stereo_image_proc::DisparityNodelet" \
  "stereo_image_proc/point_cloud2:stereo_image_proc::PointCloud2Nodelet"
write_package image_proc libimage_proc \
  "image_proc/debayer:image_proc::DebayerNodelet" \
  "image_proc/rectify:image_proc::RectifyNodelet" \
  "image_proc/resize:image_proc::ResizeNodelet" \
  "image_proc/crop_decimate:image_proc::CropDecimateNodelet" \
  "image_proc/crop_nonzero:image_proc::CropNonZeroNodelet"

# rospack caches its crawl; a new folder on the path is picked up, a changed one may not be.
rm -f "${ROS_HOME:-$HOME/.ros}/rospack_cache"* 2>/dev/null || true
if [ -n "${ROS_PACKAGE_PATH:-}" ]; then
  case ":$ROS_PACKAGE_PATH:" in
    *":$dir:"*) path="$ROS_PACKAGE_PATH" ;;
    *) path="$dir:$ROS_PACKAGE_PATH" ;;
  esac
else
  path="$dir:/usr/share"
fi
if [ "$exec_mode" = 1 ]; then
  export ROS_PACKAGE_PATH="$path"
  exec "$@"
fi
echo "$path"
