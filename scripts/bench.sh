#!/usr/bin/env bash
# What `make bench` runs: endo_stereo_bench (ours vs OpenCV BM, SGBM and the quasi-dense matcher on
# Middlebury and synthetic scenes, the 960x540 timing case, peak memory, the precision-density
# sweep), then the precision-density plot. Results: out/bench/bench.md (the printed tables),
# docs/benchmark_results.json, docs/precision_density.{csv,png}. Extra arguments go to the bench
# (e.g. --repeats 9, --quick).
set -euo pipefail
source "$(dirname "$0")/env.sh"
BENCH="$WS/devel/lib/endo_stereo/endo_stereo_bench"
if [ ! -x "$BENCH" ]; then
  echo "bench.sh: $BENCH is not built (run: make build)" >&2
  exit 1
fi
mkdir -p "$ES_ROOT/out/bench" "$ES_ROOT/docs"
if [ ! -d "$ES_ROOT/../shared/data/middlebury" ]; then
  echo "bench.sh: NOTE: ../shared/data/middlebury is missing; only synthetic scenes are scored" >&2
fi
"$BENCH" --root "$ES_ROOT" "$@" | tee "$ES_ROOT/out/bench/bench.md"
/usr/bin/python3 "$ES_ROOT/scripts/plot_precision_density.py" \
  "$ES_ROOT/docs/precision_density.csv" "$ES_ROOT/docs/precision_density.png" ||
  echo "bench.sh: the plot could not be drawn (needs /usr/bin/python3 with matplotlib)" >&2
echo "bench.sh: tables in out/bench/bench.md, plot in docs/precision_density.png"
# Other components' benchmarks plug in as scripts/bench_*.sh (run in name order, no arguments).
status=0
for extra in "$ES_ROOT"/scripts/bench_*.sh; do
  [ -e "$extra" ] || continue
  echo "bench.sh: running $(basename "$extra")"
  bash "$extra" || { echo "bench.sh: $(basename "$extra") failed" >&2; status=1; }
done
exit $status
