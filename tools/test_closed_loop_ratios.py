"""Tests of closed_loop_ratios.py: `python3 -m unittest discover -s tools` (CI runs it)."""
import contextlib
import csv
import io
import math
import os
import subprocess
import sys
import tempfile
import unittest

import closed_loop_ratios

COLUMNS = ["material", "strategy", "level", "true_flip", "env_flip", "brdf_log_err"]


def write_csv(directory, name, rows):
    path = os.path.join(directory, name)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        w.writerows(rows)
    return path


class ClosedLoopRatios(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.addCleanup(self.dir.cleanup)

    def run_main(self, *args):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            closed_loop_ratios.main(["closed_loop_ratios.py", *args])
        return out.getvalue().splitlines()

    def test_geometric_means_worst_material_and_summed_log(self):
        # Level 1: point ratios 2 and 0.5 (geomean 1), env 1 and 1, brdf 4 and 1 (geomean 2).
        product = write_csv(self.dir.name, "product.csv", [
            ["a", "adaptive", 1, 0.01, 0.02, 0.001],
            ["b", "adaptive", 1, 0.02, 0.02, 0.002],
            ["a", "uniform", 1, 9.0, 9.0, 9.0],
        ])
        trial = write_csv(self.dir.name, "trial.csv", [
            ["a", "adaptive", 1, 0.02, 0.02, 0.004],
            ["b", "adaptive", 1, 0.01, 0.02, 0.002],
        ])
        point, env, brdf, summary = self.run_main(trial, product)
        self.assertTrue(point.startswith("point  1.000 (1 worse; a 2.00; without it 0.500)"), point)
        self.assertTrue(env.startswith("env    1.000 (0 worse;"), env)
        self.assertTrue(brdf.startswith("brdf   2.000 (1 worse; a 4.00; without it 1.000)"), brdf)
        self.assertEqual(summary, "summed log +0.693; worst cell brdf L1 +100.0 %")

    def test_bootstrap_intervals_hold_the_mean_and_collapse_when_materials_agree(self):
        rows_product, rows_trial = [], []
        for i, ratio in enumerate([0.5, 0.8, 1.0, 1.25, 2.0, 0.9]):
            for level in (1, 2):
                rows_product.append([f"m{i}", "adaptive", level, 0.01, 0.02, 0.001])
                # point varies by material; env is the same ratio (0.9) everywhere; brdf unchanged.
                rows_trial.append([f"m{i}", "adaptive", level, 0.01 * ratio, 0.018, 0.001])
        product = write_csv(self.dir.name, "product.csv", rows_product)
        trial = write_csv(self.dir.name, "trial.csv", rows_trial)
        lines = self.run_main(trial, product, "--bootstrap")
        self.assertEqual(lines[4], "90 % intervals, 6 materials resampled 2000 times (seed 1):")
        point, env, brdf, summed = lines[5:]
        lo, hi = (float(x) for x in point.split("[")[1].split("]")[0].split(", "))
        mean = math.exp(sum(math.log(r) for r in [0.5, 0.8, 1.0, 1.25, 2.0, 0.9]) / 6)
        self.assertLess(lo, mean)
        self.assertGreater(hi, mean)
        self.assertLess(lo, 0.85)
        self.assertGreater(hi, 1.15)
        self.assertEqual(env, "env    [0.900, 0.900] / [0.900, 0.900]")
        self.assertEqual(brdf, "brdf   [1.000, 1.000] / [1.000, 1.000]")
        self.assertTrue(summed.startswith("summed log ["), summed)
        # The same seed gives the same intervals.
        self.assertEqual(lines, self.run_main(trial, product, "--bootstrap"))
        # A subset of the metrics: only its rows, and the summed log over them alone.
        env_only = self.run_main(trial, product, "--bootstrap", "--metrics", "env")
        self.assertEqual(env_only[1], "summed log -0.211; worst cell env L1 -10.0 %")
        self.assertEqual(env_only[3], "env    [0.900, 0.900] / [0.900, 0.900]")
        self.assertEqual(env_only[4], "summed log [-0.211, -0.211]")
        with self.assertRaisesRegex(ValueError, "unknown metric flip"):
            self.run_main(trial, product, "--metrics", "env,flip")
        # These csvs predate liu_log_err: asking for it names the missing column.
        with self.assertRaisesRegex(ValueError, "no column liu_log_err"):
            self.run_main(trial, product, "--metrics", "liu")

    def test_versus_compares_two_strategies_of_one_file(self):
        both = write_csv(self.dir.name, "both.csv", [
            ["a", "adaptive", 1, 0.02, 0.01, 0.001],
            ["a", "uniform", 1, 0.01, 0.02, 0.001],
        ])
        point, env, brdf, summary = self.run_main(both, both, "adaptive", "--versus", "uniform")
        self.assertTrue(point.startswith("point  2.000 (1 worse;"), point)
        self.assertTrue(env.startswith("env    0.500 (0 worse;"), env)
        self.assertEqual(summary, "summed log +0.000; worst cell point L1 +100.0 %")

    def test_liu_reads_its_own_column(self):
        def liu_csv(name, liu):
            path = os.path.join(self.dir.name, name)
            with open(path, "w", newline="") as f:
                w = csv.writer(f)
                w.writerow(COLUMNS + ["liu_log_err"])
                w.writerow(["a", "adaptive", 1, 0.01, 0.02, 0.001, liu])
            return path
        lines = self.run_main(liu_csv("t.csv", 0.004), liu_csv("p.csv", 0.002), "--metrics", "liu")
        self.assertEqual(lines, ["liu    2.000 (1 worse; a 2.00; without it 2.000)",
                                 "summed log +0.693; worst cell liu L1 +100.0 %"])

    def test_short_names_drop_scheme_folder_and_extension(self):
        self.assertEqual(closed_loop_ratios.short("rgl:../shared/data/rgl/satin_rosaline_rgb.bsdf"), "satin_rosaline_rgb")
        self.assertEqual(closed_loop_ratios.short("nbrdf:two-layer-silver"), "two-layer-silver")
        self.assertEqual(closed_loop_ratios.short("chrome"), "chrome")

    def test_missing_strategy_and_no_common_material_are_errors(self):
        product = write_csv(self.dir.name, "product.csv", [["a", "adaptive", 1, 0.01, 0.02, 0.001]])
        other = write_csv(self.dir.name, "other.csv", [["b", "adaptive", 1, 0.01, 0.02, 0.001]])
        with self.assertRaisesRegex(ValueError, "no rows of strategy uniform"):
            self.run_main(product, product, "uniform")
        with self.assertRaisesRegex(ValueError, "level 1: no material in both files"):
            self.run_main(other, product)

    def test_bad_input_exits_with_one_line(self):
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "closed_loop_ratios.py")
        missing = os.path.join(self.dir.name, "missing.csv")
        r = subprocess.run([sys.executable, script, missing, missing], capture_output=True, text=True)
        self.assertNotEqual(r.returncode, 0)
        self.assertEqual(len(r.stderr.strip().splitlines()), 1, r.stderr)
        self.assertTrue(r.stderr.startswith("closed_loop_ratios: "), r.stderr)


if __name__ == "__main__":
    unittest.main()
