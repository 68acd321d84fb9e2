#!/usr/bin/env bash
# Builds and runs every test (gtest for the core, rostest for the nodelet), then the core gtests
# again under ASan+UBSan (skip with ES_SKIP_ASAN=1), then prints the plain summary line
# "N passed, N failed" and exits non-zero on any failure.
set -uo pipefail
source "$(dirname "$0")/env.sh"
"$ES_ROOT/scripts/build.sh" || { echo "build failed"; echo "0 passed, 1 failed"; exit 1; }
"$ES_ROOT/scripts/build.sh" tests || { echo "building tests failed"; echo "0 passed, 1 failed"; exit 1; }
es_source_ws
rm -rf "$WS/build/test_results"
cd "$WS"
catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 run_tests -j1 ${TEST_ARGS:-} 2>&1 | tee "$WS/run_tests.log" | \
  grep -E '^\[ *(RUN|  OK|  FAILED|  PASSED|  SKIPPED) *\]|^\[ROSTEST\]|FAILURE|rostest|Error' || true

# ASan/UBSan stage (RELIABILITY.md section 3): the core gtests (test/core) built with
# -fsanitize=address,undefined in a workspace of their own (WS_ASAN, default .ws_asan, shared with
# `make asan`), run with leak detection; a sanitizer report fails the binary. Their results go
# next to the others, so the summary line below counts them. ES_SKIP_ASAN=1 skips the stage.
if [ "${ES_SKIP_ASAN:-0}" != 1 ]; then
  asan_results="$WS/build/test_results/endo_stereo_asan"
  mkdir -p "$asan_results"
  asan_fail() {  # a JUnit file with one failing case, so test_summary.py counts it
    printf '<testsuite name="asan" tests="1" failures="1"><testcase classname="ASan" name="%s">'\
'<failure message="%s"/></testcase></testsuite>\n' "$1" "$2" > "$asan_results/asan_$1_sanitizer.xml"
  }
  mapfile -t asan_tests < <(grep -oE 'catkin_add_gtest\(test_[a-z0-9_]+ test/core/' \
    "$ES_ROOT/CMakeLists.txt" | grep -oE 'test_[a-z0-9_]+' | sort -u)
  asan_ws="${WS_ASAN:-$ES_ROOT/.ws_asan}"
  asan_start=$(date +%s)
  echo "[asan] building ${#asan_tests[@]} core gtests with ASan+UBSan in $asan_ws"
  mkdir -p "$asan_ws"
  if ! WS="$asan_ws" BUILD_TYPE=RelWithDebInfo \
       CMAKE_EXTRA_ARGS="-DES_SANITIZE=address,undefined ${CMAKE_EXTRA_ARGS:-}" \
       "$ES_ROOT/scripts/build.sh" "${asan_tests[@]}" > "$asan_ws/run_tests_build.log" 2>&1; then
    tail -n 20 "$asan_ws/run_tests_build.log"
    asan_fail build "ASan build failed, see $asan_ws/run_tests_build.log"
  else
    echo "[asan] built in $(( $(date +%s) - asan_start )) s"
    for t in "${asan_tests[@]}"; do
      xml="$asan_results/asan_$t.xml"
      ASAN_OPTIONS="detect_leaks=1" \
      UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:suppressions=$ES_ROOT/scripts/ubsan.supp" \
        "$asan_ws/devel/lib/endo_stereo/$t" --gtest_output="xml:$xml" > "$asan_ws/$t.log" 2>&1
      rc=$?
      if [ "$rc" != 0 ] && ! grep -q '<failure' "$xml" 2>/dev/null; then
        # Crashed before writing results, or a report at exit (leaks): count it as a failure.
        grep -E 'ERROR: (Address|Leak)Sanitizer|runtime error' "$asan_ws/$t.log" | head -n 3
        asan_fail "$t" "exit $rc: sanitizer report or crash, see $asan_ws/$t.log"
      fi
      echo "[asan] $t: exit $rc"
    done
  fi
  echo "[asan] stage took $(( $(date +%s) - asan_start )) s"
fi
/usr/bin/python3 "$ES_ROOT/scripts/test_summary.py" "$WS/build/test_results"
