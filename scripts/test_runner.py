#!/usr/bin/env python3
"""The test runner behind `make test` (scripts/run_tests.sh) and `make test-runner-selftest`.

It takes the list of tests from the build itself (CTest's registry, where catkin_add_gtest,
add_rostest and catkin_run_tests_target record every test with its exact command), runs each
one, and decides per test from three sources that must agree:
  * the exit status of the test command: non-zero is a failure, whatever the XML says;
  * the JUnit result file the command must leave: none is a failure, by name;
  * for a rostest, the exit status of each test node, recorded by scripts/record_exit.sh (the
    launch-prefix of every <test> node): rostest itself never looks at it.
Test cases are counted from the gtest XML (a rostest's wrapper cases are not tests of their
own). A skipped case passes only when its reason says that something the test needs is absent
(its message contains "absent:", e.g. "absent: ../shared/data/real/..." or "absent: AVX-512 on
this CPU"); any other skip, a failed fixture set-up among them, fails the run.

Commands:
  run      --build DIR --stage NAME --out FILE.json [--only NAME ...] [--kind K] [--project P]
           runs the registered tests of project P (default endo_stereo), prints one line per test
           and a stage line "NAME: N passed, N failed", writes the stage's record to FILE.json.
  summary  STAGE.json ...
           prints each failure and skip, one line per stage, and last the distinct-test line
           "N passed, N failed"; exits 1 on any failure in any stage.
"""
import argparse
import glob
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

ABSENT_TAG = "absent:"
DEFAULT_TIMEOUT_S = 1500


def ctest_tests(build_dir, project):
    """The tests registered in the build, in registration order: name, kind, command, cwd,
    result file, timeout."""
    out = subprocess.run(["ctest", "--show-only=json-v1"], cwd=build_dir, check=True,
                         capture_output=True, text=True).stdout
    tests = []
    prefix = f"_ctest_{project}_"
    for t in json.loads(out)["tests"]:
        name = t["name"]
        if not name.startswith(prefix):
            continue
        kind, _, short = name[len(prefix):].partition("_")
        cmd = t["command"]
        props = {p["name"]: p["value"] for p in t.get("properties", [])}
        # catkin's form: [env.sh] python run_tests.py RESULT [--working-dir D] --return-code CMD...
        result = None
        for i, arg in enumerate(cmd):
            if arg.endswith("run_tests.py") and i + 1 < len(cmd):
                result = cmd[i + 1]
                break
        tests.append({
            "name": short, "kind": kind, "command": cmd,
            "cwd": props.get("WORKING_DIRECTORY", build_dir),
            "result": result,
            "timeout": float(props.get("TIMEOUT", DEFAULT_TIMEOUT_S)),
        })
    return tests


def case_outcome(case):
    """('passed'|'failed'|'skipped', message) of one JUnit <testcase>."""
    for tag in ("failure", "error"):
        node = case.find(tag)
        if node is not None:
            msg = (node.get("message") or node.text or "").strip()
            return "failed", msg
    node = case.find("skipped")
    if node is not None or case.get("result") == "skipped" or case.get("status") == "notrun":
        msg = ""
        if node is not None:
            msg = (node.get("message") or node.text or "").strip()
        if case.get("status") == "notrun" and not msg:
            msg = "disabled (not run)"
        return "skipped", msg
    return "passed", ""


def first_line_with(msg, tag):
    """The first line of a gtest message that holds tag, past gtest's "file:line" line."""
    lines = [l.strip() for l in msg.splitlines() if l.strip()]
    lines = [l for l in lines if not re.fullmatch(r"\S+:\d+", l)] or lines
    for l in lines:
        if tag in l:
            return l
    return lines[0] if lines else "(no reason given)"


def read_cases(path, test_name):
    """[(case id, outcome, message)] of a JUnit file; raises ValueError when unreadable."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as err:
        raise ValueError(f"unreadable result file {path}: {err}")
    cases = []
    for case in root.iter("testcase"):
        cid = f"{test_name}: {case.get('classname', '')}.{case.get('name', '')}"
        outcome, msg = case_outcome(case)
        cases.append((cid, outcome, msg))
    return cases, root


def results_snapshot(folder):
    snap = {}
    for p in glob.glob(os.path.join(folder, "**", "*"), recursive=True):
        if os.path.isfile(p):
            snap[p] = os.path.getmtime(p)
    return snap


def run_one(test, log_dir, env):
    """Runs one registered test; returns its record."""
    rec = {"name": test["name"], "kind": test["kind"], "cases": [], "problems": [],
           "seconds": 0.0}
    result = test["result"]
    results_dir = os.path.dirname(result) if result else None
    if result and os.path.exists(result):
        os.remove(result)
    before = results_snapshot(results_dir) if results_dir else {}
    log_path = os.path.join(log_dir, f"{test['kind']}_{test['name']}.log")
    start = time.time()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(test["command"], cwd=test["cwd"], stdout=log,
                                stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            rc = proc.wait(timeout=test["timeout"])
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            rc = None
    rec["seconds"] = round(time.time() - start, 1)
    rec["log"] = log_path
    if rc is None:
        rec["problems"].append(f"timed out after {test['timeout']:.0f} s")
    elif rc != 0:
        rec["problems"].append(f"exit status {rc}" + (
            f" (signal {-rc})" if rc < 0 else ""))
    if not result or not os.path.exists(result):
        rec["problems"].append(f"left no result file ({result})")
        return rec
    try:
        cases, root = read_cases(result, test["name"])
    except ValueError as err:
        rec["problems"].append(str(err))
        return rec
    if test["kind"] == "rostest":
        # The wrapper's cases are rostest's verdict on each test node (ran, left results): a
        # failure there is the rostest's, not a test case of its own.
        for cid, outcome, msg in cases:
            if outcome == "failed":
                rec["problems"].append(f"rostest: {first_line_with(msg, '')}")
        # The test nodes' own gtest results, written during this run, beside the wrapper's.
        after = results_snapshot(results_dir)
        fresh = sorted(p for p, m in after.items()
                       if p.endswith(".xml") and p != result and before.get(p) != m)
        node_results = [p for p in fresh if os.path.basename(p).startswith("rosunit-")]
        if not node_results:
            rec["problems"].append("no test node left results")
        for p in node_results:
            node = os.path.basename(p)[len("rosunit-"):-len(".xml")]
            try:
                node_cases, _ = read_cases(p, f"{test['name']}/{node}")
            except ValueError as err:
                rec["problems"].append(str(err))
                continue
            rec["cases"].extend(node_cases)
            exit_file = p + ".exit"
            if not os.path.exists(exit_file):
                rec["problems"].append(
                    f"test node {node}: no exit status recorded (its <test> needs "
                    f"launch-prefix=\"$(find endo_stereo)/scripts/record_exit.sh\")")
            else:
                with open(exit_file) as f:
                    node_rc = f.read().strip()
                if node_rc != "0":
                    rec["problems"].append(f"test node {node}: exit status {node_rc}")
    else:
        rec["cases"] = cases
        if not cases:
            rec["problems"].append("result file holds no test case")
    return rec


def judge(rec):
    """Splits a record into passed cases, failures and skips (with reasons)."""
    passed, failures, skips = [], [], []
    for cid, outcome, msg in rec["cases"]:
        if outcome == "passed":
            passed.append(cid)
        elif outcome == "failed":
            failures.append((cid, first_line_with(msg, "")))
        elif ABSENT_TAG in msg:
            skips.append((cid, first_line_with(msg, ABSENT_TAG), True))
        else:
            skips.append((cid, first_line_with(msg, ""), False))
            failures.append((cid, "skipped without an absent-data or absent-hardware reason: "
                             + first_line_with(msg, "")))
    for p in rec["problems"]:
        failures.append((f"{rec['name']} [{rec['kind']}]", p))
    return passed, failures, skips


def cmd_run(args):
    tests = ctest_tests(args.build, args.project)
    if args.kind:
        tests = [t for t in tests if t["kind"] == args.kind]
    if args.only:
        wanted = set(args.only)
        missing = sorted(wanted - {t["name"] for t in tests})
        tests = [t for t in tests if t["name"] in wanted]
    else:
        missing = []
    log_dir = os.path.join(os.path.dirname(os.path.abspath(args.out)), f"logs_{args.stage}")
    os.makedirs(log_dir, exist_ok=True)
    env = dict(os.environ)
    records = []
    for name in missing:  # asked for, but the build registered no such test
        records.append({"name": name, "kind": "?", "cases": [], "seconds": 0.0, "log": "",
                        "problems": ["not registered in the build"]})
    print(f"[{args.stage}] {len(tests)} registered tests", flush=True)
    for test in tests:
        rec = run_one(test, log_dir, env)
        records.append(rec)
        passed, failures, skips = judge(rec)
        verdict = "FAIL" if failures else "ok"
        extra = f", {len(skips)} skipped" if skips else ""
        print(f"[{args.stage}] {verdict:4} {test['kind']} {test['name']}: {len(passed)} passed, "
              f"{len(failures)} failed{extra} ({rec['seconds']} s)", flush=True)
        if failures:
            for cid, why in failures:
                print(f"[{args.stage}]      FAILED {cid}: {why}")
            print(f"[{args.stage}]      log: {rec['log']} (last lines below)")
            try:
                with open(rec["log"]) as f:
                    tail = f.readlines()[-15:]
                for line in tail:
                    print(f"[{args.stage}]      | {line.rstrip()}")
            except OSError:
                pass
    with open(args.out, "w") as f:
        json.dump({"stage": args.stage, "records": records}, f, indent=1)
    n_pass = sum(len(judge(r)[0]) for r in records)
    n_fail = sum(len(judge(r)[1]) for r in records)
    print(f"{args.stage}: {n_pass} passed, {n_fail} failed")
    return 1 if n_fail else 0


def cmd_summary(args):
    stages = []
    for path in args.stage_files:
        try:
            with open(path) as f:
                stages.append(json.load(f))
        except (OSError, ValueError) as err:
            stages.append({"stage": os.path.basename(path), "records": [],
                           "error": f"no stage record ({err})"})
    status = {}  # distinct test id -> 'passed' | 'failed'
    lines = []
    for st in stages:
        n_pass = n_fail = 0
        if st.get("error"):
            print(f"FAILED: stage {st['stage']}: {st['error']}")
            status[f"stage {st['stage']}"] = "failed"
            n_fail += 1
        for rec in st["records"]:
            passed, failures, skips = judge(rec)
            for cid in passed:
                status.setdefault(cid, "passed")
            for cid, why in failures:
                print(f"FAILED ({st['stage']}): {cid}: {why}")
                status[cid] = "failed"
            for cid, why, ok in skips:
                if ok:
                    print(f"SKIPPED ({st['stage']}): {cid}: {why}")
                    status.setdefault(cid, "skipped")
            n_pass += len(passed)
            n_fail += len(failures)
        n_skip = sum(1 for r in st["records"] for s in judge(r)[2] if s[2])
        label = "ASan" if st["stage"] == "asan" else st["stage"]
        lines.append(f"{label}: {n_pass} passed, {n_fail} failed, {n_skip} skipped (data or "
                     f"hardware absent)")
    for line in lines:
        print(line)
    n_pass = sum(1 for v in status.values() if v == "passed")
    n_fail = sum(1 for v in status.values() if v == "failed")
    n_skip = sum(1 for v in status.values() if v == "skipped")
    if n_pass + n_fail == 0:
        print("no test ran")
        n_fail = 1
    print(f"distinct tests: {n_pass + n_fail + n_skip} ran, {n_skip} skipped with a stated "
          f"absence, {n_fail} failed")
    print(f"{n_pass} passed, {n_fail} failed")
    return 1 if n_fail else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--build", required=True)
    r.add_argument("--stage", required=True)
    r.add_argument("--out", required=True)
    r.add_argument("--project", default="endo_stereo")
    r.add_argument("--only", nargs="*")
    r.add_argument("--kind", choices=["gtest", "rostest"], help="only the tests of this kind")
    s = sub.add_parser("summary")
    s.add_argument("stage_files", nargs="+")
    args = ap.parse_args()
    return cmd_run(args) if args.cmd == "run" else cmd_summary(args)


if __name__ == "__main__":
    sys.exit(main())
