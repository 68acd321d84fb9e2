#!/usr/bin/env bash
# Builds endo_stereo in the catkin workspace $WS (default ./.ws). Extra arguments go to
# catkin_make (e.g. a target name).
#
# Layout: WS/src/endo_stereo -> WS/endo_stereo, a folder holding one link per top-level entry of
# the repository (CMakeLists.txt, package.xml, src, include, test, config, launch, ...), skipping
# dot-entries and git-ignored ones (.ws, out, build folders). The package folder therefore never
# contains the workspace, and tools that search it following links (rosrun's `find -L`, rospack,
# roslaunch) cannot loop. WS/shared -> the repository's ../shared keeps `${CMAKE_CURRENT_SOURCE_DIR}/../shared`
# (after REALPATH) pointing at the shared data, as it does from the repository itself.
set -euo pipefail
source "$(dirname "$0")/env.sh"
mkdir -p "$WS/src" "$WS/endo_stereo"
view="$WS/endo_stereo"
ignored() {  # is $1 (a top-level name) git-ignored? (no git: only the known build folders)
  if git -C "$ES_ROOT" rev-parse --git-dir > /dev/null 2>&1; then
    git -C "$ES_ROOT" check-ignore -q -- "$1"
  else
    case "$1" in ws|ws_*|out|build*) return 0 ;; *) return 1 ;; esac
  fi
}
for entry in "$ES_ROOT"/*; do
  name="$(basename "$entry")"
  [ -e "$entry" ] || continue
  ignored "$name" && continue
  [ "$(readlink "$view/$name" 2>/dev/null || true)" = "$entry" ] || ln -sfn "$entry" "$view/$name"
done
for link in "$view"/*; do  # entries removed from the repository, or ignored since
  [ -L "$link" ] || continue
  name="$(basename "$link")"
  if [ ! -e "$ES_ROOT/$name" ] || ignored "$name"; then rm -f "$link"; fi
done
[ "$(readlink "$WS/shared" 2>/dev/null || true)" = "$ES_ROOT/../shared" ] || \
  ln -sfn "$ES_ROOT/../shared" "$WS/shared"
# Replaces the earlier layout's link to the repository itself (ln -sfn replaces a link).
[ "$(readlink "$WS/src/endo_stereo" 2>/dev/null || true)" = "$view" ] || \
  ln -sfn "$view" "$WS/src/endo_stereo"
BUILD_TYPE="${BUILD_TYPE:-Release}"
JOBS="${JOBS:-$(nproc)}"
cd "$WS"
catkin_make -DCMAKE_BUILD_TYPE="$BUILD_TYPE" -DPYTHON_EXECUTABLE=/usr/bin/python3 \
  -DCATKIN_ENABLE_TESTING=ON ${CMAKE_EXTRA_ARGS:-} -j"$JOBS" "$@"
