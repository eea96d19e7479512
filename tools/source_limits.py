#!/usr/bin/env python3
"""Fails if a non-test source file is over 800 lines; lists non-test functions over 100 lines.

    python3 tools/source_limits.py [DIR ...]   # default: shared firmware host cli lab

A file's non-test part is everything before its `#[cfg(test)]` line; files named `tests.rs` and
files under a `tests/`, `benches/` or `examples/` folder are tests. A function's length runs from
its `fn` line to the line of its closing brace at the same indentation (rustfmt's layout).
"""
import os
import re
import sys

FILE_MAX = 800
FN_MAX = 100
DEFAULT = ["shared", "firmware", "host", "cli", "lab"]
SKIP_DIRS = {"tests", "benches", "examples", "target", "fuzz"}
FN = re.compile(r"^(\s*)(pub(\([^)]*\))?\s+)?(const\s+)?(async\s+)?(unsafe\s+)?fn\s+(\w+)")


def sources(root):
    for base, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d not in SKIP_DIRS)
        for f in sorted(files):
            if f.endswith(".rs") and f != "tests.rs":
                yield os.path.join(base, f)


def non_test_lines(path):
    lines = open(path, encoding="utf-8").read().split("\n")
    for i, line in enumerate(lines):
        if line.strip() == "#[cfg(test)]":
            return lines[:i]
    return lines


def long_functions(lines):
    for i, line in enumerate(lines):
        m = FN.match(line)
        if not m or line.rstrip().endswith(";"):
            continue
        indent = m.group(1)
        for j in range(i + 1, len(lines)):
            if lines[j] == indent + "}":
                if j - i + 1 > FN_MAX:
                    yield m.group(7), i + 1, j - i + 1
                break


def main():
    roots = sys.argv[1:] or [d for d in DEFAULT if os.path.isdir(d)]
    too_long, fns = [], []
    for root in roots:
        for path in sources(root):
            lines = non_test_lines(path)
            if len(lines) > FILE_MAX:
                too_long.append((len(lines), path))
            fns += [(n, path, name, at) for name, at, n in long_functions(lines)]
    for n, path, name, at in sorted(fns, reverse=True):
        print(f"long function: {path}:{at} {name} ({n} lines)")
    for n, path in sorted(too_long, reverse=True):
        print(f"FAIL: {path}: {n} non-test lines (limit {FILE_MAX})")
    print(f"source limits: {len(too_long)} files over {FILE_MAX} lines, {len(fns)} functions over {FN_MAX} lines")
    sys.exit(1 if too_long else 0)


if __name__ == "__main__":
    main()
