#!/usr/bin/env python3
"""Sorts ThreadSanitizer reports (log_path files of `make tsan`) by where the racing accesses are.

A report counts against endo_stereo when the top frame (the first one outside the TSan runtime) of
either racing access is in endo_stereo's code (a source path under the repository, or one of its
libraries). Reports whose both accesses sit inside libraries we do not build (roscpp's and
nodeletlib's boost::shared_ptr reference counts, OpenCV/oneTBB hand-overs) are listed apart: those
libraries are not instrumented, so TSan does not see their atomics and reports orderings that do
exist. Exit status 1 when any report counts against endo_stereo.

Usage: tsan_triage.py REPORT_FILE...
"""
import re
import sys
from collections import Counter

OURS = re.compile(r"endo_stereo|/src/core/|/src/ros/")


def parse_frame(line):
    """(function, location, module) of a '#N function location (module+offset)' line."""
    m = re.match(r"\s*#\d+ (.*) \(([^()]*)\)\s*$", line)
    if not m:
        return None
    head, module = m.group(1), m.group(2).split("+")[0]
    fn, _, location = head.rpartition(" ")
    return fn, location, module


def top_frames(report):
    """(function, location, module) of the first non-runtime frame of each racing access."""
    tops = []
    current = None
    for line in report.split("\n"):
        if re.match(r"\s*(Previous )?(write|read|Write|Read|Atomic|atomic)", line):
            current = []
            tops.append(current)
            continue
        if re.match(r"\s*(Thread|Location|Mutex|SUMMARY)", line):
            current = None
            continue
        if current is not None and not current:
            f = parse_frame(line)
            if f and "libtsan" not in f[2] and "sanitizer" not in f[1]:
                current.append(f)
    found = [t[0] for t in tops if t][:2]
    if not found:  # not a race (a mutex misuse, a signal): the first frame of the report's stack
        for line in report.split("\n"):
            f = parse_frame(line)
            if f and "libtsan" not in f[2] and "sanitizer" not in f[1]:
                return [f]
    return found


def main(paths):
    text = ""
    for p in paths:
        with open(p, errors="replace") as f:
            text += f.read()
    reports = text.split("WARNING: ThreadSanitizer")[1:]
    ours, theirs = [], Counter()
    for r in reports:
        kind = r.split("\n", 1)[0].split("(")[0].strip(": ")
        tops = top_frames(r)
        if any(OURS.search(loc) or OURS.search(mod) for _, loc, mod in tops):
            ours.append((kind, tops))
        else:
            theirs[(kind, tuple(sorted({mod for _, _, mod in tops})))] += 1
    print("ThreadSanitizer reports: %d in total, %d with a racing access in endo_stereo's code"
          % (len(reports), len(ours)))
    for (kind, mods), n in theirs.most_common():
        print("  %4d %s inside uninstrumented %s" % (n, kind, ", ".join(mods) or "?"))
    for kind, tops in ours:
        print("  endo_stereo: %s: %s" % (kind, " / ".join("%s at %s" % (f[:60], loc)
                                                          for f, loc, _ in tops)))
    return 1 if ours else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
