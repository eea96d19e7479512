#!/usr/bin/env python3
"""A closed-loop trial against the product: per metric (point FLIP, env FLIP, brdf_log_err) and level,
the geometric mean over materials of the ratio trial / product for one strategy, then the number of
materials worse, the worst material and the mean without it; last, the summed log of the means and
the worst cell (docs/trials/). With --bootstrap, each cell's and the summed log's 90 % interval from
resampling the materials (the same resample for every cell, so the sum keeps their correlation): how
far a verdict on one set of materials can be told from chance.

    python3 tools/closed_loop_ratios.py TRIAL/closed-loop.csv PRODUCT/closed-loop.csv [strategy] [--bootstrap] [--metrics point,env,brdf,liu]
    python3 tools/closed_loop_ratios.py CSV CSV adaptive --versus uniform --bootstrap
"""
import argparse
import csv
import math
import os
import random
import statistics
import sys
from collections import defaultdict

RESAMPLES = 2000
SEED = 1


def short(material):
    """A material's name without its scheme, folder and extension (rgl:../x/satin.bsdf -> satin)."""
    return os.path.splitext(os.path.basename(material.split(":", 1)[-1]))[0]


METRICS = [("point", "true_flip"), ("env", "env_flip"), ("brdf", "brdf_log_err"), ("liu", "liu_log_err")]
DEFAULT_METRICS = "point,env,brdf"


def load(path, strategy):
    rows = defaultdict(dict)
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["strategy"] == strategy:
                rows[int(r["level"])][r["material"]] = r
    if not rows:
        raise ValueError(f"{path}: no rows of strategy {strategy}")
    return rows


def bootstrap(new, old, metrics=METRICS):
    """Per metric, per level: the 90 % interval of the ratio's geometric mean; and of the summed log."""
    cells = [(name, col, level) for name, col in metrics for level in sorted(new)]
    mats = sorted(set.intersection(*(set(new[l]) & set(old.get(l, {})) for _, _, l in cells)))
    if not mats:
        raise ValueError("no material in every cell of both files")
    logs = [[math.log(float(new[l][m][col]) / float(old[l][m][col])) for m in mats] for _, col, l in cells]
    rng = random.Random(SEED)
    means = [[] for _ in cells]
    sums = []
    for _ in range(RESAMPLES):
        pick = [rng.randrange(len(mats)) for _ in mats]
        total = 0.0
        for c, cell in enumerate(logs):
            mean = sum(cell[i] for i in pick) / len(pick)
            means[c].append(mean)
            total += mean
        sums.append(total)

    def interval(values):
        cuts = statistics.quantiles(values, n=20, method="inclusive")
        return cuts[0], cuts[-1]

    intervals = {(name, level): tuple(map(math.exp, interval(m))) for (name, _, level), m in zip(cells, means)}
    return len(mats), intervals, interval(sums)


def main(argv):
    parser = argparse.ArgumentParser(prog="closed_loop_ratios.py")
    parser.add_argument("trial")
    parser.add_argument("product")
    parser.add_argument("strategy", nargs="?", default="adaptive")
    parser.add_argument("--bootstrap", action="store_true", help="90 %% intervals over resampled materials")
    parser.add_argument("--metrics", default=DEFAULT_METRICS,
                        help="comma-separated subset of point,env,brdf,liu (liu: csvs from 2026-12-08 on)")
    parser.add_argument("--versus", metavar="STRATEGY", help="the product file's strategy, if not the trial's "
                        "(e.g. adaptive against uniform in one csv: issue 25's equal-directions ratios)")
    args = parser.parse_args(argv[1:])
    names = args.metrics.split(",")
    unknown = sorted(set(names) - {name for name, _ in METRICS})
    if unknown:
        raise ValueError(f"unknown metric {', '.join(unknown)} (point, env, brdf or liu)")
    metrics = [(name, col) for name, col in METRICS if name in names]
    for path in (args.trial, args.product):
        with open(path, newline="") as f:
            header = next(csv.reader(f), [])
        missing = [col for _, col in metrics if col not in header]
        if missing:
            raise ValueError(f"{path}: no column {', '.join(missing)} (a csv made before it was recorded)")
    new, old = load(args.trial, args.strategy), load(args.product, args.versus or args.strategy)
    total, worst = 0.0, (-math.inf, "")
    for name, col in metrics:
        cells = []
        for level in sorted(new):
            mats = sorted(set(new[level]) & set(old.get(level, {})))
            if not mats:
                raise ValueError(f"level {level}: no material in both files")
            logs = sorted((math.log(float(new[level][m][col]) / float(old[level][m][col])), m) for m in mats)
            mean = sum(x for x, _ in logs) / len(logs)
            rest = logs[:-1] or logs
            total += mean
            if mean > worst[0]:
                worst = (mean, f"{name} L{level}")
            cells.append(
                f"{math.exp(mean):.3f} ({sum(x > 0 for x, _ in logs)} worse; {short(logs[-1][1])} "
                f"{math.exp(logs[-1][0]):.2f}; without it {math.exp(sum(x for x, _ in rest) / len(rest)):.3f})"
            )
        print(f"{name:6s}", " / ".join(cells))
    print(f"summed log {total:+.3f}; worst cell {worst[1]} {100 * (math.exp(worst[0]) - 1):+.1f} %")
    if args.bootstrap:
        n, intervals, (lo, hi) = bootstrap(new, old, metrics)
        print(f"90 % intervals, {n} materials resampled {RESAMPLES} times (seed {SEED}):")
        for name, _ in metrics:
            print(f"{name:6s}", " / ".join(
                f"[{intervals[(name, level)][0]:.3f}, {intervals[(name, level)][1]:.3f}]" for level in sorted(new)))
        print(f"summed log [{lo:+.3f}, {hi:+.3f}]")


if __name__ == "__main__":
    try:
        main(sys.argv)
    except (OSError, ValueError, KeyError, ZeroDivisionError) as e:
        sys.exit(f"closed_loop_ratios: {e}")
