#!/usr/bin/env bash
# What `make bench` runs: real recordings first, generated scenes second, then BENCHMARKS.md.
#   1. real (when ../shared/data/real is present; each run says so when it is not):
#      - the in-vivo video real/hamlyn_invivo1, all 150 frames, search 0..127 (endo_stereo_evaluate:
#        ours with and without priors, OpenCV BM and SGBM; density, jumps, flicker, coverage, time);
#      - the real 960x540 frame: the SCARED ds1 pair rectified with its calibration
#        (endo_stereo_cli --calib --out-rectified), its centre 960x540 crop, search 48..111: the
#        same pair 10 times (full search; ours without priors is the full-search time) and a
#        moving sequence of 75 frames in which the crop window moves on a circle of radius 24 px
#        (one turn, about 2 px per frame);
#      - the in-vivo video and the moving sequence again with --threads 1 (ours only): time per
#        stage at 1 thread beside the runs above (OpenCV's default thread count, one per CPU);
#      - pairs with ground truth (endo_stereo_eval --peers): real/scared_ds1_kf2_gt (search 0..95)
#        and the Middlebury scenes;
#      - the depth-edge filter's trade-off (scripts/edge_tradeoff.py): the in-vivo video and the
#        pairs with ground truth again for each setting of its thresholds, docs/edge_tradeoff.png;
#   2. generated: a 60-frame surgical sequence from endo_stereo_generate (endo_stereo_evaluate);
#      endo_stereo_bench (Middlebury and synthetic scenes beside BM, SGBM and OpenCV's
#      quasi-dense matcher, the 960x540 timing case, peak memory, the precision-density sweep)
#      and its plot;
#   3. the other components' scripts/bench_*.sh (scripts/bench_ros.sh: the nodelet beside
#      stereo_image_proc on real and generated bags at 25 fps);
#   4. scripts/bench_report.py: BENCHMARKS.md, docs/benchmark_results.json and the figures
#      docs/bench_*.png from this run's outputs (out/bench, out/bench_ros), with the commit, the
#      machine and every command.
# Extra arguments go to endo_stereo_bench (e.g. --repeats 9, --quick).
set -uo pipefail
source "$(dirname "$0")/env.sh"
es_source_ws
cd "$ES_ROOT"
BIN="$WS/devel/lib/endo_stereo"
for exe in endo_stereo_evaluate endo_stereo_eval endo_stereo_cli endo_stereo_generate endo_stereo_bench; do
  if [ ! -x "$BIN/$exe" ]; then
    echo "bench.sh: $BIN/$exe is not built (run: make build)" >&2
    exit 1
  fi
done
# Commands are recorded as run from the repository root.
REL_BIN="${BIN#"$ES_ROOT"/}"
REAL_REL="../shared/data/real"
OUT=out/bench
rm -rf "$OUT"
mkdir -p "$OUT" docs
COMMANDS="$OUT/commands.tsv"
: > "$COMMANDS"
status=0

# record ID CMD...: runs CMD from the repository root, its stdout to out/bench/ID.md, its stderr
# to out/bench/ID.log, and records the command line for the report.
record() {
  local id=$1 line="" arg
  shift
  for arg in "$@"; do  # quoted as a shell would need it (single quotes around spaces and such)
    if [[ "$arg" =~ ^[A-Za-z0-9_./%:=,+-]+$ ]]; then line+="$arg "; else line+="'$arg' "; fi
  done
  line="${line% }"
  printf '%s\t%s\n' "$id" "$line" >> "$COMMANDS"
  echo "bench.sh: [$id] $line"
  if ! "$@" > "$OUT/$id.md" 2> "$OUT/$id.log"; then
    echo "bench.sh: [$id] failed, see $OUT/$id.log" >&2
    status=1
  fi
}

# --- 1. real recordings ---------------------------------------------------------------------------
if [ -d "$REAL_REL" ]; then
  record invivo "$REL_BIN/endo_stereo_evaluate" \
    --left "$REAL_REL/hamlyn_invivo1/left/%04d.png" --right "$REAL_REL/hamlyn_invivo1/right/%04d.png" \
    --min-disparity 0 --max-disparity 127 --label "real/hamlyn_invivo1" --threads 2 --quiet \
    --out "$OUT/invivo"
  record invivo_t1 "$REL_BIN/endo_stereo_evaluate" \
    --left "$REAL_REL/hamlyn_invivo1/left/%04d.png" --right "$REAL_REL/hamlyn_invivo1/right/%04d.png" \
    --min-disparity 0 --max-disparity 127 --label "real/hamlyn_invivo1, 1 thread" \
    --methods ours,ours-no-priors --threads 1 --quiet --json "$OUT/invivo_t1.json"
  record scared_rectify "$REL_BIN/endo_stereo_cli" \
    --left "$REAL_REL/scared_ds1_pair/Left_Image.png" --right "$REAL_REL/scared_ds1_pair/Right_Image.png" \
    --calib "$REAL_REL/scared_ds1_pair/calib_scared_official_ds1-3.yaml" \
    --min-disparity 48 --max-disparity 111 --out-rectified "$OUT/scared_rect"
  record real960_static "$REL_BIN/endo_stereo_evaluate" \
    --left "$OUT/scared_rect_left.png" --right "$OUT/scared_rect_right.png" --crop 960x540 \
    --repeat 10 --min-disparity 48 --max-disparity 111 --label "SCARED ds1 960x540, static" \
    --threads 2 --quiet --out "$OUT/real960_static"
  record real960_moving "$REL_BIN/endo_stereo_evaluate" \
    --left "$OUT/scared_rect_left.png" --right "$OUT/scared_rect_right.png" --crop 960x540 \
    --pan 75 --min-disparity 48 --max-disparity 111 --label "SCARED ds1 960x540, moving crop" \
    --threads 2 --quiet --out "$OUT/real960_moving"
  record real960_moving_t1 "$REL_BIN/endo_stereo_evaluate" \
    --left "$OUT/scared_rect_left.png" --right "$OUT/scared_rect_right.png" --crop 960x540 \
    --pan 75 --min-disparity 48 --max-disparity 111 \
    --label "SCARED ds1 960x540, moving crop, 1 thread" --methods ours,ours-no-priors \
    --threads 1 --quiet --json "$OUT/real960_moving_t1.json"
  record groundtruth "$REL_BIN/endo_stereo_eval" --peers \
    --gt-pair "$REAL_REL/scared_ds1_kf2_gt" --gt-range 0:95 --json "$OUT/groundtruth.json"
  record edge_tradeoff /usr/bin/python3 scripts/edge_tradeoff.py --bin "$REL_BIN" --real "$REAL_REL" \
    --out "$OUT" --png docs/edge_tradeoff.png
else
  echo "bench.sh: NOTE: $REAL_REL is absent: no real-recording tables in this run" >&2
  if [ -d ../shared/data/middlebury ]; then
    record groundtruth "$REL_BIN/endo_stereo_eval" --peers --json "$OUT/groundtruth.json"
  fi
fi

# --- 2. generated scenes ----------------------------------------------------------------------------
record generate "$REL_BIN/endo_stereo_generate" --out "$OUT/generated_seq" --frames 60 --no-gt
read -r GMIN GMAX < <(/usr/bin/python3 -c "import yaml,sys; s=yaml.safe_load(open(sys.argv[1])); print(s['min_disparity'], s['max_disparity'])" "$OUT/generated_seq/sequence.yaml")
record generated "$REL_BIN/endo_stereo_evaluate" \
  --left "$OUT/generated_seq/left/%06d.png" --right "$OUT/generated_seq/right/%06d.png" \
  --min-disparity "$GMIN" --max-disparity "$GMAX" --label "generated surgical sequence" \
  --quiet --out "$OUT/generated"
if [ ! -d ../shared/data/middlebury ]; then
  echo "bench.sh: NOTE: ../shared/data/middlebury is missing; only synthetic scenes are scored" >&2
fi
record scenes "$REL_BIN/endo_stereo_bench" --root . --json "$OUT/scenes.json" \
  --curve docs/precision_density.csv "$@"
/usr/bin/python3 scripts/plot_precision_density.py docs/precision_density.csv docs/precision_density.png ||
  echo "bench.sh: the plot could not be drawn (needs /usr/bin/python3 with matplotlib)" >&2

# --- 3. other components' benchmarks (run in name order, no arguments) -------------------------------
for extra in scripts/bench_*.sh; do
  [ -e "$extra" ] || continue
  echo "bench.sh: running $extra"
  printf '%s\t%s\n' "$(basename "$extra" .sh)" "$extra" >> "$COMMANDS"
  bash "$extra" || { echo "bench.sh: $extra failed" >&2; status=1; }
done

# --- 4. the results page ------------------------------------------------------------------------------
/usr/bin/python3 scripts/bench_report.py --out "$OUT" --ros out/bench_ros || status=1
echo "bench.sh: BENCHMARKS.md, docs/benchmark_results.json and docs/bench_*.png written"
exit $status
