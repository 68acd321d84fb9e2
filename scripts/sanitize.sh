#!/usr/bin/env bash
# Sanitizer builds of endo_stereo, each in a catkin workspace of its own (git-ignored, hidden:
# .ws_asan, .ws_tsan; roslaunch/rostest file lookups skip dot-folders, so they do not follow
# WS/src/endo_stereo back into the repository, the reason the main workspace is .ws).
#
#   scripts/sanitize.sh asan   AddressSanitizer + UndefinedBehaviorSanitizer (CMake ES_SANITIZE=
#                              address,undefined) in WS_ASAN (default .ws_asan), then the whole test
#                              suite: the core gtests with leak detection, then the rostests with
#                              the ASan runtime preloaded into the (uninstrumented) nodelet manager
#                              and Python (leak detection off there: Python's own allocations are
#                              not ours). Last line: "N passed, N failed"; exit 1 on any failure or
#                              any sanitizer report.
#   scripts/sanitize.sh tsan   ThreadSanitizer (ES_SANITIZE=thread) in WS_TSAN (default .ws_tsan):
#                              builds the nodelet and the standalone node, then runs the node under
#                              a fast stream of pairs while dynamic_reconfigure updates are hammered
#                              from another process (scripts/soak.sh in its TSan configuration,
#                              TSAN_FRAMES pairs, default 600). Exit 1 when the run fails or a
#                              ThreadSanitizer report has a racing access in endo_stereo's code
#                              (scripts/tsan_triage.py; scripts/tsan.supp for roscpp's lock order).
#
# Environment: JOBS (default 1: the machines are shared), WS_ASAN, WS_TSAN, BUILD_TYPE
# (default RelWithDebInfo, -O2 -g, so stack traces have lines), ASAN_SKIP_BUILD=1 (rerun the tests
# of an existing ASan build; make's test targets still rebuild what changed).
set -uo pipefail
ES_ROOT="$(cd "$(dirname "$0")/.." && pwd)"
mode="${1:-asan}"
JOBS="${JOBS:-1}"
export JOBS
BUILD_TYPE="${BUILD_TYPE:-RelWithDebInfo}"
export BUILD_TYPE

start_s=$(date +%s)
elapsed() { echo $(( $(date +%s) - start_s )); }

# Sanitizer reports: count them in the given logs, print the first ones.
report_count() {
  local n
  n=$(cat "$@" 2>/dev/null | grep -cE '^(==[0-9]+==ERROR: (Address|Leak)Sanitizer|WARNING: ThreadSanitizer|SUMMARY: (Address|Leak|Thread|UndefinedBehavior)Sanitizer)|runtime error: ' || true)
  echo "${n:-0}"
}

case "$mode" in
  asan)
    export WS="${WS_ASAN:-$ES_ROOT/.ws_asan}"
    # shellcheck disable=SC1091
    source "$ES_ROOT/scripts/env.sh"
    export CMAKE_EXTRA_ARGS="-DES_SANITIZE=address,undefined ${CMAKE_EXTRA_ARGS:-}"
    # halt_on_error makes a UBSan report fail the test that triggered it (scripts/ubsan.supp says
    # why it holds no entry).
    export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:suppressions=$ES_ROOT/scripts/ubsan.supp"
    mkdir -p "$WS"
    echo "[asan] building in $WS ($BUILD_TYPE, jobs $JOBS)"
    if [ "${ASAN_SKIP_BUILD:-0}" = 1 ]; then
      echo "[asan] ASAN_SKIP_BUILD=1: using the existing build"
    elif ! "$ES_ROOT/scripts/build.sh" > "$WS/sanitize_build.log" 2>&1 || \
       ! "$ES_ROOT/scripts/build.sh" tests >> "$WS/sanitize_build.log" 2>&1; then
      tail -n 30 "$WS/sanitize_build.log"
      echo "[asan] build failed (log: $WS/sanitize_build.log)"
      echo "0 passed, 1 failed"
      exit 1
    fi
    echo "[asan] built in $(elapsed) s"
    es_source_ws
    rm -rf "$WS/build/test_results"
    logs="$WS/sanitize_logs"
    rm -rf "$logs"; mkdir -p "$logs"
    runner="/usr/bin/python3 $ES_ROOT/scripts/test_runner.py"
    # 1) gtests (linked with the ASan runtime): leaks are ours, detect them. Each test's exit
    # status is checked (a sanitizer report is a non-zero exit), a missing result is a failure.
    ASAN_OPTIONS="detect_leaks=1:abort_on_error=0:log_path=$logs/gtest" \
      $runner run --build "$WS/build" --kind gtest --stage asan_gtests --out "$logs/gtests.json"
    echo "[asan] gtests done at $(elapsed) s"
    # 2) rostests: the nodelet manager and rostest are not instrumented; preload the runtime.
    LD_PRELOAD="$(gcc -print-file-name=libasan.so)" \
    ASAN_OPTIONS="detect_leaks=0:verify_asan_link_order=0:log_path=$logs/rostest" \
      $runner run --build "$WS/build" --kind rostest --stage asan_rostests \
        --out "$logs/rostests.json"
    echo "[asan] rostests done at $(elapsed) s"
    # A report from a process that is not a test (the manager, a node) changes no exit status:
    # every report line counts as one more failure.
    reports=$(report_count "$logs"/gtest.* "$logs"/rostest.*)
    extra=()
    if [ "$reports" != 0 ]; then
      echo "[asan] $reports sanitizer report line(s); first ones:"
      cat "$logs"/gtest.* "$logs"/rostest.* 2>/dev/null | \
        grep -E -A12 '==ERROR|runtime error|SUMMARY' | head -n 60
      printf '{"stage": "asan_reports", "records": [{"name": "sanitizer reports", "kind": "logs", "cases": [], "seconds": 0, "log": "%s", "problems": ["%s report line(s) in %s"]}]}\n' \
        "$logs" "$reports" "$logs" > "$logs/reports.json"
      extra=("$logs/reports.json")
    fi
    echo "[asan] total $(elapsed) s (build + tests); logs in $logs"
    $runner summary "$logs/gtests.json" "$logs/rostests.json" "${extra[@]}"
    ;;
  tsan)
    export WS="${WS_TSAN:-$ES_ROOT/.ws_tsan}"
    # shellcheck disable=SC1091
    source "$ES_ROOT/scripts/env.sh"
    export CMAKE_EXTRA_ARGS="-DES_SANITIZE=thread ${CMAKE_EXTRA_ARGS:-}"
    mkdir -p "$WS"
    echo "[tsan] building the nodelet in $WS ($BUILD_TYPE, jobs $JOBS)"
    if ! "$ES_ROOT/scripts/build.sh" endo_stereo_node endo_stereo_nodelet > "$WS/sanitize_build.log" 2>&1; then
      tail -n 30 "$WS/sanitize_build.log"
      echo "[tsan] build failed (log: $WS/sanitize_build.log)"
      exit 1
    fi
    echo "[tsan] built in $(elapsed) s"
    logs="$WS/sanitize_logs"
    rm -rf "$logs"; mkdir -p "$logs"
    # The run itself is the soak driver, shorter, with the reconfigure hammer on; the node is
    # instrumented (it links the TSan runtime), so nothing needs preloading.
    # OpenCV's parallel_for_ runs on oneTBB, which is not instrumented: every hand-over between
    # the caller and a TBB worker is reported (thousands of false positives, seen here, in the
    # matcher's stripes and SIFT's keypoint vectors). So OpenCV runs serially in this run (the
    # nodelet calls cv::setNumThreads(0) when built with TSan, the matcher's num_threads = 0 keeps
    # it, the SIFT rectification-quality check off)
    # and TSan watches the nodelet's own threads: ROS callbacks, the processing thread,
    # dynamic_reconfigure, diagnostics. The matcher's stripes are not covered by this run.
    OPENCV_FOR_THREADS_NUM=1 \
    TSAN_OPTIONS="halt_on_error=0:second_deadlock_stack=1:suppressions=$ES_ROOT/scripts/tsan.supp:log_path=$logs/tsan_report" \
    SOAK_FRAMES="${TSAN_FRAMES:-600}" SOAK_OUT="$logs" SOAK_LABEL=tsan_soak SOAK_TIMEOUT_S=1200 \
      "$ES_ROOT/scripts/soak.sh" soak --param matcher/num_threads=0 \
        --param rectify/quality_stride=1000000 --max-rss-growth-kb 100000000  # TSan's own memory grows
    rc=$?
    # Reports whose racing accesses are both inside uninstrumented libraries (roscpp's shared_ptr
    # reference counts, OpenCV/TBB) are listed but do not fail the run; any report with a racing
    # access in endo_stereo's code does (scripts/tsan_triage.py).
    triage=0
    if ls "$logs"/tsan_report* > /dev/null 2>&1; then
      /usr/bin/python3 "$ES_ROOT/scripts/tsan_triage.py" "$logs"/tsan_report* || triage=1
    else
      echo "[tsan] no ThreadSanitizer report"
    fi
    echo "[tsan] run exit $rc"
    echo "[tsan] total $(elapsed) s; logs in $logs"
    [ "$rc" = 0 ] && [ "$triage" = 0 ]
    ;;
  *)
    echo "usage: $0 asan|tsan" >&2
    exit 2
    ;;
esac
