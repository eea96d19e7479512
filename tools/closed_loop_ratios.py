#!/usr/bin/env python3
"""A closed-loop trial against the product: per metric (point FLIP, env FLIP, brdf_log_err) and level,
the geometric mean over materials of the ratio trial / product for one strategy, then the number of
materials worse, the worst material and the mean without it; last, the summed log of the means and
the worst cell (docs/trials/).

    python3 tools/closed_loop_ratios.py TRIAL/closed-loop.csv PRODUCT/closed-loop.csv [strategy]
"""
import csv
import math
import os
import sys
from collections import defaultdict

def short(material):
    """A material's name without its scheme, folder and extension (rgl:../x/satin.bsdf -> satin)."""
    return os.path.splitext(os.path.basename(material.split(":", 1)[-1]))[0]


METRICS = [("point", "true_flip"), ("env", "env_flip"), ("brdf", "brdf_log_err")]


def load(path, strategy):
    rows = defaultdict(dict)
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["strategy"] == strategy:
                rows[int(r["level"])][r["material"]] = r
    if not rows:
        raise ValueError(f"{path}: no rows of strategy {strategy}")
    return rows


def main(argv):
    if len(argv) not in (3, 4):
        raise ValueError("usage: closed_loop_ratios.py TRIAL.csv PRODUCT.csv [strategy]")
    strategy = argv[3] if len(argv) == 4 else "adaptive"
    new, old = load(argv[1], strategy), load(argv[2], strategy)
    total, worst = 0.0, (-math.inf, "")
    for name, col in METRICS:
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


if __name__ == "__main__":
    try:
        main(sys.argv)
    except (OSError, ValueError, KeyError, ZeroDivisionError) as e:
        sys.exit(f"closed_loop_ratios: {e}")
