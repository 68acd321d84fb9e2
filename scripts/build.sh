#!/usr/bin/env bash
# Builds endo_stereo in the catkin workspace $WS (default ./.ws): WS/src/endo_stereo -> repository.
# Extra arguments go to catkin_make (e.g. a target name).
set -euo pipefail
source "$(dirname "$0")/env.sh"
mkdir -p "$WS/src"
ln -sfn "$ES_ROOT" "$WS/src/endo_stereo"
BUILD_TYPE="${BUILD_TYPE:-Release}"
JOBS="${JOBS:-$(nproc)}"
cd "$WS"
catkin_make -DCMAKE_BUILD_TYPE="$BUILD_TYPE" -DPYTHON_EXECUTABLE=/usr/bin/python3 \
  -DCATKIN_ENABLE_TESTING=ON ${CMAKE_EXTRA_ARGS:-} -j"$JOBS" "$@"
