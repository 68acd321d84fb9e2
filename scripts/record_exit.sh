#!/usr/bin/env bash
# launch-prefix of every rostest <test> node: runs the node and records its exit status beside
# its gtest result file (RESULT.xml.exit), because rostest itself reads only the XML and never
# the exit status. scripts/test_runner.py requires the record and fails a non-zero status: a test
# node that wrote a passing XML and then crashed, leaked or exited non-zero is a failure.
"$@"
rc=$?
for arg in "$@"; do
  case "$arg" in
    --gtest_output=xml:*) echo "$rc" > "${arg#--gtest_output=xml:}.exit" ;;
  esac
done
exit "$rc"
