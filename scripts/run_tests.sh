#!/usr/bin/env bash
# `make test`: builds, runs every test the build registers, then the core gtests and the fuzz
# regressions again under ASan+UBSan (ES_SKIP_ASAN=1 skips that stage, and says so), and prints
# the summary; its last line is "N passed, N failed" over distinct tests, and the exit status is
# non-zero on any failure in any stage.
#
# scripts/test_runner.py does the accounting (its header says how): the list of tests comes from
# the build's CTest registry, every test's exit status is checked, a test that leaves no result
# fails by name, and a skip passes only when it names something absent (data or CPU feature).
set -uo pipefail
source "$(dirname "$0")/env.sh"
runner="/usr/bin/python3 $ES_ROOT/scripts/test_runner.py"
stages_dir="$WS/test_stages"
rm -rf "$stages_dir"
mkdir -p "$stages_dir"
fail_stage() {  # a stage that could not run at all: one named failure in the summary
  printf '{"stage": "%s", "records": [{"name": "%s", "kind": "build", "cases": [], "seconds": 0, "log": "%s", "problems": ["%s"]}]}\n' \
    "$1" "$2" "$3" "$4" > "$stages_dir/$1.json"
}

# Main stage: the package and every test target (the build's status is checked), then each test.
if ! "$ES_ROOT/scripts/build.sh" > "$WS/build.log" 2>&1 || \
   ! "$ES_ROOT/scripts/build.sh" tests >> "$WS/build.log" 2>&1; then
  tail -n 30 "$WS/build.log"
  fail_stage main build "$WS/build.log" "build failed, see $WS/build.log"
else
  es_source_ws
  rm -rf "$WS/build/test_results"
  $runner run --build "$WS/build" --stage main --out "$stages_dir/main.json"
fi

# ASan/UBSan stage (RELIABILITY.md section 3): the core gtests (test/core) and the fuzz-regression
# replays built with -fsanitize=address,undefined in a workspace of their own (WS_ASAN, default
# .ws_asan, shared with `make asan`), run with leak detection; a sanitizer report is a non-zero
# exit, which fails the test.
if [ "${ES_SKIP_ASAN:-0}" != 1 ]; then
  mapfile -t asan_tests < <(grep -oE 'catkin_add_gtest\(test_[a-z0-9_]+ test/(core|fuzz)/' \
    "$ES_ROOT/CMakeLists.txt" | grep -oE 'test_[a-z0-9_]+' | sort -u)
  mapfile -t -O "${#asan_tests[@]}" asan_tests < <(grep -oE '^ *fuzz_replay_test\([a-z_]+' \
    "$ES_ROOT/CMakeLists.txt" | sed -E 's/.*\(/test_fuzz_regressions_/' | sort -u)
  asan_ws="${WS_ASAN:-$ES_ROOT/.ws_asan}"
  asan_start=$(date +%s)
  echo "[asan] building ${#asan_tests[@]} tests with ASan+UBSan in $asan_ws"
  mkdir -p "$asan_ws"
  if ! WS="$asan_ws" BUILD_TYPE=RelWithDebInfo \
       CMAKE_EXTRA_ARGS="-DES_SANITIZE=address,undefined ${CMAKE_EXTRA_ARGS:-}" \
       "$ES_ROOT/scripts/build.sh" "${asan_tests[@]}" > "$asan_ws/run_tests_build.log" 2>&1; then
    tail -n 20 "$asan_ws/run_tests_build.log"
    fail_stage asan asan_build "$asan_ws/run_tests_build.log" \
      "ASan build failed, see $asan_ws/run_tests_build.log"
  else
    echo "[asan] built in $(( $(date +%s) - asan_start )) s"
    rm -rf "$asan_ws/build/test_results"
    ASAN_OPTIONS="detect_leaks=1" \
    UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:suppressions=$ES_ROOT/scripts/ubsan.supp" \
      $runner run --build "$asan_ws/build" --stage asan --out "$stages_dir/asan.json" \
        --only "${asan_tests[@]}"
  fi
  echo "[asan] stage took $(( $(date +%s) - asan_start )) s"
else
  echo "[asan] stage skipped (ES_SKIP_ASAN=1): the ASan line is absent from the summary"
fi
# The runner itself, on planted defects (test/runner_selftest): a runner that stops catching them
# fails the run.
"$ES_ROOT/scripts/runner_selftest.sh" --stage "$stages_dir/selftest.json"

$runner summary "$stages_dir/main.json" "$stages_dir/selftest.json" $( [ -f "$stages_dir/asan.json" ] && echo "$stages_dir/asan.json")
