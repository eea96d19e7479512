#!/usr/bin/env python3
"""Replay the closed loop's stop rule on a lab schedule trial, constants chosen on training.

The product's estimator is `change FLIP x ratio`, the ratio the median of true / change FLIP over
the training materials' levels (host/src/plan/closed_loop.rs). A schedule with other level steps
(`gonio-lab closed-loop --trial grids:...`) needs its own ratio, so this script derives it from the
training run's rows of one strategy and replays `--target-flip` on other runs' rows of the same
strategy, as `closed-loop.md`'s "Stop rules" table does for `adaptive`:

    tools/stop_replay.py [--quantile Q] TRAINING.csv STRATEGY [TEST.csv ...]

`--quantile Q` sets the ratio at the training ratios' Q quantile instead of the median (a more
cautious rule for Q > 0.5: later stops, more scans meeting the target).

Quantiles and geometric means follow lab/src/plan/tradeoff/closed_loop.rs (`quantile`, `geomean`).
"""
import csv
import math
import sys

TARGETS = (0.02, 0.01)


def quantile(v, q):
    v = sorted(x for x in v if math.isfinite(x))
    if not v:
        return math.nan
    i = min(max(math.ceil(len(v) * q), 1), len(v)) - 1
    return v[i]


def geomean(v):
    v = [x for x in v if math.isfinite(x) and x > 0]
    return math.exp(sum(math.log(x) for x in v) / max(len(v), 1))


def num(s):
    return float(s) if s not in ("", None) else None


def rows_of(path, strategy):
    try:
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f) if r["strategy"] == strategy]
    except (OSError, KeyError, csv.Error) as e:
        sys.exit(f"stop_replay: {path}: {e}")
    if not rows:
        sys.exit(f"stop_replay: {path}: no rows of strategy {strategy!r}")
    by = {}
    for r in rows:
        by.setdefault(r["material"], []).append(r)
    for levels in by.values():
        levels.sort(key=lambda r: int(r["level"]))
    return by


def replay(levels, ratio, target):
    """(true FLIP at the stop level, its minutes, the oracle's minutes or None)."""
    stop = levels[-1]
    for r in levels:
        change = num(r["change_flip"])
        if change is not None and change * ratio <= target:
            stop = r
            break
    oracle = next((r for r in levels if num(r["true_flip"]) <= target), None)
    return num(stop["true_flip"]), num(stop["minutes"]), num(oracle["minutes"]) if oracle else None


def main():
    args = sys.argv[1:]
    q = 0.5
    if args[:1] == ["--quantile"]:
        try:
            q = float(args[1])
        except (IndexError, ValueError):
            q = math.nan
        if not 0.0 < q < 1.0:
            sys.exit("stop_replay: --quantile needs a number in (0, 1)")
        args = args[2:]
    if len(args) < 2:
        sys.exit(__doc__.strip().splitlines()[0] + "\nusage: stop_replay.py [--quantile Q] TRAINING.csv STRATEGY [TEST.csv ...]")
    train, strategy, tests = args[0], args[1], args[2:]
    ratios = [
        num(r["true_flip"]) / max(num(r["change_flip"]), 1e-9)
        for levels in rows_of(train, strategy).values()
        for r in levels
        if num(r["change_flip"]) is not None
    ]
    ratio = quantile(ratios, q)
    print(f"{strategy}: true / change FLIP over {len(ratios)} training levels: median {quantile(ratios, 0.5):.3f}, "
          f"5% {quantile(ratios, 0.05):.3f}, 95% {quantile(ratios, 0.95):.3f}; the rule's ratio ({q} quantile) {ratio:.3f}")
    print("| run | target FLIP | scans meeting it at the stop level | time / oracle (geomean, max) | scans no level met |")
    print("|---|---|---|---|---|")
    for path in [train] + tests:
        by = rows_of(path, strategy)
        for target in TARGETS:
            hit, n, times, unmet = 0, 0, [], 0
            for levels in by.values():
                true, minutes, oracle = replay(levels, ratio, target)
                n += 1
                hit += true <= target
                if oracle is None:
                    unmet += 1
                else:
                    times.append(minutes / oracle)
            print(f"| {path} | {target} | {hit} of {n} | {geomean(times):.2f}, {quantile(times, 1.0):.2f} | {unmet} |")


if __name__ == "__main__":
    main()
