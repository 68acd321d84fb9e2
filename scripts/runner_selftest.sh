#!/usr/bin/env bash
# `make test-runner-selftest`: builds the planted defects of test/runner_selftest (a failing
# fixture set-up, a crash and a non-zero exit after a passing XML, a missing result, an
# unexplained skip, a rostest node that crashes after a passing XML) beside controls that must
# pass, runs scripts/test_runner.py on them, and checks that it reports exactly the planted
# defects as failures. Last line: "runner self-test: N planted, N caught"; exits 1 on any
# planted defect not caught or any control reported as failed.
# With --stage FILE it also writes its verdict as a stage record for the summary of `make test`.
set -uo pipefail
source "$(dirname "$0")/env.sh"
es_source_ws  # record_exit.sh is found as $(find endo_stereo)
src="$ES_ROOT/test/runner_selftest"
dir="$WS/runner_selftest"
rm -rf "$dir/test_results"
mkdir -p "$dir"
stage_file=""
[ "${1:-}" = "--stage" ] && stage_file="$2"
if ! { cmake -S "$src" -B "$dir" -DCMAKE_BUILD_TYPE=Release > "$dir/build.log" 2>&1 &&
       cmake --build "$dir" -j"$(nproc)" >> "$dir/build.log" 2>&1; }; then
  tail -n 20 "$dir/build.log"
  echo "runner self-test: build failed, see $dir/build.log"
  [ -n "$stage_file" ] && printf '{"stage": "selftest", "records": [{"name": "runner_selftest", "kind": "selftest", "cases": [], "seconds": 0, "log": "%s", "problems": ["the planted tests did not build"]}]}\n' "$dir/build.log" > "$stage_file"
  exit 1
fi
export ROS_PACKAGE_PATH="$src/ros:${ROS_PACKAGE_PATH:-}"
/usr/bin/python3 "$ES_ROOT/scripts/test_runner.py" run --build "$dir" --project planted \
  --stage planted --out "$dir/planted.json" > "$dir/runner.log" 2>&1
/usr/bin/python3 - "$src/planted.txt" "$dir/planted.json" "$stage_file" "$ES_ROOT/scripts" <<'PY'
import json, sys
sys.path.insert(0, sys.argv[4])
from test_runner import judge
expect = {}
for line in open(sys.argv[1]):
    words = line.split("#")[0].split()
    if words:
        expect[words[0]] = (words[1], " ".join(words[2:]))
records = {r["name"]: r for r in json.load(open(sys.argv[2]))["records"]}
planted = caught = 0
problems = []
for name, (want, reason) in expect.items():
    rec = records.get(name)
    if rec is None:
        problems.append(f"{name}: not run by the runner")
        print(f"  MISSED  {name}: the runner did not run it")
        continue
    failures = judge(rec)[1]
    if want == "caught":
        planted += 1
        hits = [why for _, why in failures if reason in why]
        if hits:
            caught += 1
            print(f"  caught  {name}: {hits[0]}")
        elif failures:
            problems.append(f"{name}: failed, but not for the planted reason ({reason})")
            print(f"  MISSED  {name}: failed for another reason: {failures[0][1]}")
        else:
            problems.append(f"{name}: planted defect reported as passing")
            print(f"  MISSED  {name}: reported as passing")
    elif failures:
        problems.append(f"{name}: control reported as failed: {failures[0][1]}")
        print(f"  WRONG   {name} (control) reported as failed: {failures[0][1]}")
    else:
        print(f"  passes  {name} (control)")
for name in records:
    if name not in expect:
        problems.append(f"{name}: registered but not in planted.txt")
if sys.argv[3]:
    with open(sys.argv[3], "w") as f:
        json.dump({"stage": "selftest", "records": [{
            "name": "runner_selftest", "kind": "selftest", "seconds": 0, "log": sys.argv[2],
            "cases": [("runner_selftest: planted defects caught", "passed" if not problems
                       else "failed", "; ".join(problems))],
            "problems": []}]}, f)
print(f"runner self-test: {planted} planted, {caught} caught")
sys.exit(1 if problems else 0)
PY
