#!/usr/bin/env python3
"""Fails if two top-level modules of a crate import each other, directly or around a longer loop.

    python3 tools/module_cycles.py [CRATE_SRC_DIR ...]   # default: every crate of the workspace

A module is a top-level file or folder of a crate's src/ (files of one module may use each other).
An edge M -> N is any `crate::N` path in M's non-test code (test modules, `tests.rs` files and
everything after a file's `#[cfg(test)]` line are skipped: a test may reach across modules).
Prints every cycle found and exits 1 if there is one.
"""
import os
import re
import sys

DEFAULT = ["shared/src", "firmware/src", "host/src", "cli/src", "lab/src"]
PATH = re.compile(r"\bcrate::(\{[^;]*?\}|\w+)", re.S)


def non_test_code(text):
    text = re.sub(r"//[^\n]*", "", text)
    cut = text.find("#[cfg(test)]")
    return text if cut < 0 else text[:cut]


def targets(code):
    for m in PATH.finditer(code):
        g = m.group(1)
        if g.startswith("{"):
            depth, name, names = 0, "", []
            for ch in g[1:-1]:
                if ch in "{(":
                    depth += 1
                elif ch in "})":
                    depth -= 1
                if depth == 0 and ch == ",":
                    names.append(name)
                    name = ""
                else:
                    name += ch
            names.append(name)
            for n in names:
                n = n.strip().split("::")[0].strip()
                if re.fullmatch(r"\w+", n):
                    yield n
        else:
            yield g


def graph(src):
    mods = {}
    for entry in sorted(os.listdir(src)):
        path = os.path.join(src, entry)
        if entry in ("lib.rs", "main.rs"):
            continue
        name = entry[:-3] if entry.endswith(".rs") else entry
        files = []
        if os.path.isdir(path):
            for root, _, fs in os.walk(path):
                files += [os.path.join(root, f) for f in fs if f.endswith(".rs") and f != "tests.rs"]
        elif entry.endswith(".rs"):
            files = [path]
        mods[name] = files
    edges = {m: set() for m in mods}
    for m, files in mods.items():
        for f in files:
            for n in targets(non_test_code(open(f, encoding="utf-8").read())):
                if n in mods and n != m:
                    edges[m].add(n)
    return edges


def cycles(edges):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def main():
    dirs = sys.argv[1:] or [d for d in DEFAULT if os.path.isdir(d)]
    bad = 0
    for src in dirs:
        edges = graph(src)
        found = cycles(edges)
        for comp in found:
            pairs = [f"{a} -> {b}" for a in comp for b in sorted(edges[a]) if b in comp]
            print(f"{src}: import cycle among {', '.join(comp)} ({'; '.join(pairs)})")
        bad += len(found)
    print(f"module cycles: {bad} in {len(dirs)} crates")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
