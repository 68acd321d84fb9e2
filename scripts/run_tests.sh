#!/usr/bin/env bash
# Builds and runs every test (gtest for the core, rostest for the nodelet), then prints the plain
# summary line "N passed, N failed" and exits non-zero on any failure.
set -uo pipefail
source "$(dirname "$0")/env.sh"
"$ES_ROOT/scripts/build.sh" || { echo "build failed"; echo "0 passed, 1 failed"; exit 1; }
"$ES_ROOT/scripts/build.sh" tests || { echo "building tests failed"; echo "0 passed, 1 failed"; exit 1; }
es_source_ws
rm -rf "$WS/build/test_results"
cd "$WS"
catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 run_tests -j1 ${TEST_ARGS:-} 2>&1 | tee "$WS/run_tests.log" | \
  grep -E '^\[ *(RUN|  OK|  FAILED|  PASSED|  SKIPPED) *\]|^\[ROSTEST\]|FAILURE|rostest|Error' || true
/usr/bin/python3 "$ES_ROOT/scripts/test_summary.py" "$WS/build/test_results"
