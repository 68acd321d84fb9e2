#!/usr/bin/env bash
# A rostest test node that writes a passing gtest result file, then exits as $1 says:
# "ok" (exit 0) or "crash" (killed by SIGSEGV, as a crash at shutdown would be).
mode="$1"; shift
out=""
for arg in "$@"; do
  case "$arg" in --gtest_output=xml:*) out="${arg#--gtest_output=xml:}" ;; esac
done
mkdir -p "$(dirname "$out")"
cat > "$out" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<testsuites tests="1" failures="0" disabled="0" errors="0" name="AllTests">
  <testsuite name="PlantedNode" tests="1" failures="0" disabled="0" skipped="0" errors="0">
    <testcase name="Passes" status="run" result="completed" classname="PlantedNode" />
  </testsuite>
</testsuites>
XML
[ "$mode" = crash ] && kill -SEGV $$
exit 0
