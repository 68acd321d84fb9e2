#!/usr/bin/env python3
"""Counts JUnit test cases under a catkin test_results folder; prints failures and the plain line
'N passed, N failed' last; exits 1 on any failure or when no test ran."""
import glob
import os
import sys
import xml.etree.ElementTree as ET

root = sys.argv[1]
passed, failed, skipped = 0, 0, 0
failures = []
files = sorted(glob.glob(os.path.join(root, "**", "*.xml"), recursive=True))
for path in files:
    try:
        tree = ET.parse(path)
    except ET.ParseError as err:
        failed += 1
        failures.append(f"{path}: unreadable result file ({err})")
        continue
    cases = list(tree.iter("testcase"))
    if not cases:
        # A test binary that crashed or never wrote results: catkin writes a MISSING-*.xml or an
        # empty suite with failures/errors attributes.
        suite = tree.getroot()
        if int(suite.get("failures", 0) or 0) + int(suite.get("errors", 0) or 0) > 0:
            failed += 1
            failures.append(f"{path}: suite failed without test cases")
        continue
    for case in cases:
        name = f"{case.get('classname', '')}.{case.get('name', '')}"
        if case.find("failure") is not None or case.find("error") is not None:
            failed += 1
            node = case.find("failure") if case.find("failure") is not None else case.find("error")
            msg = (node.get("message") or node.text or "").strip().splitlines()
            failures.append(f"{os.path.basename(path)}: {name}: {msg[0] if msg else ''}")
        elif case.find("skipped") is not None or case.get("status") == "notrun":
            skipped += 1
        else:
            passed += 1
for f in failures:
    print("FAILED:", f)
print(f"result files: {len(files)}; skipped: {skipped}")
if passed + failed == 0:
    print("no test ran")
    failed = 1
print(f"{passed} passed, {failed} failed")
sys.exit(1 if failed else 0)
