#!/usr/bin/env bash
# libFuzzer harnesses of endo_stereo (test/fuzz/fuzz_*.cpp), built with clang-14 and
# -fsanitize=fuzzer,address,undefined directly against the core sources (no catkin, no ROS).
#
# Usage: scripts/fuzz.sh [run|build|regress|minimize] [HARNESS...]
#   run       (default) build, then fuzz each harness for FUZZ_SECONDS (60), one at a time, from
#             the corpus kept in test/fuzz/corpus/HARNESS plus the crash regressions in
#             test/fuzz/regressions/HARNESS; prints executions and crashes per harness and exits 1
#             on any crash (the input is saved under $FUZZ_DIR/artifacts/HARNESS/).
#   build     build only.
#   regress   run every kept corpus and regression input once (seconds; no fuzzing).
#   minimize  merge what the last runs found into the kept corpus (only inputs that add coverage),
#             keeping the hand-written seeds and the smallest found inputs within
#             FUZZ_CORPUS_MAX_KB (default 8) per harness.
# HARNESS: pipeline matcher camera_info opencv_stereo params raw_image (default: all).
# Environment: FUZZ_SECONDS, FUZZ_DIR (default $ES_ROOT/build_fuzz, git-ignored), JOBS (make jobs,
# default 1), CXX (default clang++-14), FUZZ_RSS_MB (default 2048), FUZZ_TIMEOUT_S (per input, 10).
set -euo pipefail
ES_ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cmd="${1:-run}"
case "$cmd" in run|build|regress|minimize) shift || true ;; *) cmd=run ;; esac
ALL=(pipeline matcher camera_info opencv_stereo params raw_image)
if [ $# -gt 0 ]; then HARNESSES=("$@"); else HARNESSES=("${ALL[@]}"); fi
FUZZ_DIR="${FUZZ_DIR:-$ES_ROOT/build_fuzz}"
FUZZ_SECONDS="${FUZZ_SECONDS:-60}"
JOBS="${JOBS:-1}"
CXX="${CXX:-clang++-14}"
FUZZ_RSS_MB="${FUZZ_RSS_MB:-2048}"
FUZZ_TIMEOUT_S="${FUZZ_TIMEOUT_S:-10}"
FUZZ_CORPUS_MAX_KB="${FUZZ_CORPUS_MAX_KB:-8}"

# --- toolchain: clang-14 and its compiler-rt (libFuzzer lives in libclang-rt-14-dev).
need=()
command -v "$CXX" >/dev/null 2>&1 || need+=(clang-14)
ls /usr/lib/llvm-14/lib/clang/*/lib/linux/libclang_rt.fuzzer-x86_64.a >/dev/null 2>&1 || \
  need+=(libclang-rt-14-dev)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" || \
      { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
          --no-install-recommends "${need[@]}"; }
  else
    echo "[fuzz] ERROR: missing ${need[*]}: sudo apt-get install -y ${need[*]}" >&2
    exit 1
  fi
fi

# --- build: one object per core source (instrumented for coverage, not linked with a main), one
# binary per harness. A generated Makefile with -MMD dependencies rebuilds only what changed.
build() {
  mkdir -p "$FUZZ_DIR/obj"
  local mk="$FUZZ_DIR/Makefile"
  {
    echo "CXX := $CXX"
    echo "CXXFLAGS := -std=c++17 -O1 -gline-tables-only -fno-omit-frame-pointer \\"
    echo "  -fsanitize=address,undefined -fno-sanitize-recover=all \\"
    echo "  -I$ES_ROOT/include -I$ES_ROOT/src/core $(pkg-config --cflags opencv4 eigen3 yaml-cpp) -MMD -MP"
    echo "LIBS := $(pkg-config --libs opencv4 yaml-cpp) -lpthread"
    echo "CORE_OBJS := \\"
    for src in $(find "$ES_ROOT/src/core" -name "*.cpp" | sort); do
      echo "  obj/core_$(basename "${src%.cpp}").o \\"
    done
    echo ""
    echo "all: $(printf 'fuzz_%s ' "${HARNESSES[@]}")"
    for src in $(find "$ES_ROOT/src/core" -name "*.cpp" | sort); do
      echo "obj/core_$(basename "${src%.cpp}").o: $src"
      printf '\t$(CXX) $(CXXFLAGS) -fsanitize=fuzzer-no-link -c $< -o $@\n'
    done
    for h in "${ALL[@]}"; do
      echo "obj/fuzz_$h.o: $ES_ROOT/test/fuzz/fuzz_$h.cpp"
      printf '\t$(CXX) $(CXXFLAGS) -fsanitize=fuzzer-no-link -c $< -o $@\n'
      echo "fuzz_$h: obj/fuzz_$h.o \$(CORE_OBJS)"
      printf '\t$(CXX) -fsanitize=fuzzer,address,undefined $^ $(LIBS) -o $@\n'
    done
    echo "-include obj/*.d"
  } > "$mk"
  echo "[fuzz] building ${HARNESSES[*]} in $FUZZ_DIR (jobs: $JOBS)"
  make -s -C "$FUZZ_DIR" -j"$JOBS" $(printf 'fuzz_%s ' "${HARNESSES[@]}")
}

dict_args() {
  local d="$ES_ROOT/test/fuzz/$1.dict"
  [ -f "$d" ] && echo "-dict=$d" || true
}

# Seed directories that exist (libFuzzer refuses a missing one).
seed_dirs() {
  local h="$1" d
  for d in "$ES_ROOT/test/fuzz/corpus/$h" "$ES_ROOT/test/fuzz/regressions/$h"; do
    [ -d "$d" ] && echo "$d"
  done
  return 0
}

build
[ "$cmd" = build ] && exit 0

export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:allocator_may_return_null=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
summary="$FUZZ_DIR/summary.txt"
: > "$summary"
failures=0
total_execs=0

for h in "${HARNESSES[@]}"; do
  bin="$FUZZ_DIR/fuzz_$h"
  log="$FUZZ_DIR/logs/$h.log"
  mkdir -p "$FUZZ_DIR/logs" "$FUZZ_DIR/artifacts/$h" "$FUZZ_DIR/work/$h"
  mapfile -t seeds < <(seed_dirs "$h")
  common=(-rss_limit_mb="$FUZZ_RSS_MB" -timeout="$FUZZ_TIMEOUT_S" -print_final_stats=1
          -artifact_prefix="$FUZZ_DIR/artifacts/$h/" $(dict_args "$h"))
  case "$cmd" in
    regress)
      [ ${#seeds[@]} -gt 0 ] || { echo "[fuzz] $h: no kept inputs"; continue; }
      set +e
      "$bin" "${common[@]}" -runs=0 "${seeds[@]}" > "$log" 2>&1
      rc=$?
      set -e
      ;;
    minimize)
      # Merge the kept corpus and what the runs found (inputs that add coverage only), then keep
      # the hand-written seeds (named files) plus the smallest found inputs within the budget.
      new="$FUZZ_DIR/minimized/$h"
      rm -rf "$new"; mkdir -p "$new" "$ES_ROOT/test/fuzz/corpus/$h"
      set +e
      "$bin" "${common[@]}" -merge=1 "$new" "$ES_ROOT/test/fuzz/corpus/$h" "$FUZZ_DIR/work/$h" \
        > "$log" 2>&1
      rc=$?
      set -e
      if [ "$rc" != 0 ]; then
        echo "[fuzz] $h: merge failed (see $log); corpus kept as is"
        continue
      fi
      keep="$FUZZ_DIR/minimized/$h.keep"
      rm -rf "$keep"; mkdir -p "$keep"
      find "$ES_ROOT/test/fuzz/corpus/$h" -type f ! -regex '.*/[0-9a-f]\{40\}$' -exec cp {} "$keep/" \;
      budget=$(( FUZZ_CORPUS_MAX_KB * 1024 - $(cat "$keep"/* 2>/dev/null | wc -c) ))
      while read -r size f; do
        [ -e "$keep/$(basename "$f")" ] && continue
        [ "$size" -le "$budget" ] || break
        cp "$f" "$keep/"
        budget=$((budget - size))
      done < <(find "$new" -type f -printf '%s %p\n' | sort -n)
      find "$ES_ROOT/test/fuzz/corpus/$h" -type f -delete
      cp "$keep"/* "$ES_ROOT/test/fuzz/corpus/$h/"
      echo "[fuzz] $h: corpus now $(ls "$ES_ROOT/test/fuzz/corpus/$h" | wc -l) files," \
        "$(cat "$ES_ROOT/test/fuzz/corpus/$h"/* | wc -c) bytes (merge kept $(ls "$new" | wc -l))"
      continue
      ;;
    run)
      echo "[fuzz] $h: fuzzing for ${FUZZ_SECONDS} s"
      set +e
      "$bin" "${common[@]}" -max_total_time="$FUZZ_SECONDS" "$FUZZ_DIR/work/$h" "${seeds[@]}" \
        > "$log" 2>&1
      rc=$?
      set -e
      ;;
  esac
  execs=$(grep -oE 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -oE '[0-9]+$' | tail -n1)
  execs="${execs:-0}"
  total_execs=$((total_execs + execs))
  cov=$(grep -oE 'cov: [0-9]+' "$log" | tail -n1 | grep -oE '[0-9]+' || true)
  artifacts=$(find "$FUZZ_DIR/artifacts/$h" -type f -newer "$bin" | wc -l)
  if [ "$rc" != 0 ]; then
    failures=$((failures + 1))
    line="$h: FAILED (exit $rc) after $execs executions; see $log and $FUZZ_DIR/artifacts/$h/"
    grep -E 'ERROR: (AddressSanitizer|libFuzzer|LeakSanitizer)|runtime error|ES_FUZZ_CHECK|SUMMARY' \
      "$log" | head -n 5 | sed 's/^/    /' || true
  else
    line="$h: ok, $execs executions, coverage ${cov:-?} edges, new artifacts $artifacts"
  fi
  echo "[fuzz] $line"
  echo "$line" >> "$summary"
done
echo "[fuzz] total: $total_execs executions, $failures harness(es) failing" | tee -a "$summary"
[ "$failures" = 0 ]
