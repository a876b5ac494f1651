#!/usr/bin/env python3
"""bench/case_coverage.py, which chose the cases the ASan stage leaves out
(bench/RELIABILITY.md, "What each CI stage covers"): its reading of
llvm-cov's LCOV text and its choice, on hand-made cases whose answer is
worked out below. Standard library only; run by ctest (case_coverage_test).
"""
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import unittest

REPO = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))
TOOL = os.path.join(REPO, "bench", "case_coverage.py")
spec = importlib.util.spec_from_file_location("case_coverage", TOOL)
case_coverage = importlib.util.module_from_spec(spec)
spec.loader.exec_module(case_coverage)


class ProductItems(unittest.TestCase):
    def test_counts_run_lines_and_taken_branch_directions_of_product_sources_only(self):
        lcov = "\n".join([
            f"SF:{REPO}/preprocess/octree/a.cpp",
            "DA:10,0",          # not run
            "DA:11,3",
            "BRDA:11,0,0,2",    # taken twice
            "BRDA:11,0,1,-",    # its line never ran
            "BRDA:11,0,2,0",    # never taken
            "end_of_record",
            f"SF:{REPO}/tests/a_test.cpp",  # the tests' own code
            "DA:5,1",
            "end_of_record",
            "SF:/usr/include/flann/flann.hpp",  # a library's header
            "DA:7,1",
            "end_of_record",
            f"SF:{REPO}/client/render/b.cpp",
            "DA:3,1",
            "end_of_record",
        ])
        self.assertEqual(case_coverage.product_items(lcov),
                         {"preprocess/octree/a.cpp:11", "preprocess/octree/a.cpp:11:0:0", "client/render/b.cpp:3"})


def write_cases(folder, cases):
    os.makedirs(os.path.join(folder, "cases"))
    with open(os.path.join(folder, "cases", "some_test.json"), "w") as f:
        json.dump({name: {"test": "some_test", "seconds": s, "exit": status, "processes": processes, "items": items}
                   for name, (s, items, status, processes) in cases.items()}, f)


def dropped(folder, *args):
    out = subprocess.run([sys.executable, TOOL, "report", "--out", folder, *args], check=True, capture_output=True,
                         text=True).stdout
    return [line.split()[0] for line in out.split("every item still run:")[1].splitlines() if line.startswith("  ")]


class Report(unittest.TestCase):
    def test_drops_the_slowest_first_only_while_every_item_stays_run(self):
        # Slowest first: A.Slow's a is run by Bad.Input and A.Fast too, its b
        # by A.Mid, so it goes (b is now A.Mid's alone). A.Unique alone runs
        # d. A.Mid is b's last case. Bad.Input matches --keep. A.Fast's a
        # (Bad.Input) and c (A.Mid) stay run: it goes too. (Written in no
        # order of their times.)
        with tempfile.TemporaryDirectory() as folder:
            write_cases(folder, {"A.Fast": (1, ["a", "c"], 0, 1), "Bad.Input": (7, ["a"], 0, 1),
                                 "A.Slow": (10, ["a", "b"], 0, 2), "A.Mid": (8, ["b", "c"], 0, 1), "A.Unique": (9, ["d"], 0, 3)})
            self.assertEqual(dropped(folder, "--min-seconds", "0", "--keep", "^Bad\\."), ["A.Slow", "A.Fast"])
            # With no case kept by name, Bad.Input (7 s) goes before A.Fast,
            # which then is a's last case and stays.
            self.assertEqual(dropped(folder, "--min-seconds", "0", "--keep", "(?!)"), ["A.Slow", "Bad.Input"])
            # Cases faster than --min-seconds are never dropped.
            self.assertEqual(dropped(folder, "--min-seconds", "5", "--keep", "^Bad\\."), ["A.Slow"])

    def test_keeps_cases_whose_measurement_is_incomplete(self):
        # A failed case, one whose test passed but whose processes left no
        # profile (a killed process writes none), and one whose profile holds
        # no product line would otherwise go first: every item they show is
        # run by another case (or they show none).
        with tempfile.TemporaryDirectory() as folder:
            write_cases(folder, {"F.Failed": (20, ["a"], 1, 1), "F.NoProfile": (15, [], 0, 0), "F.NoItems": (12, [], 0, 1),
                                 "F.Other": (1, ["a"], 0, 1)})
            self.assertEqual(dropped(folder, "--min-seconds", "0"), ["F.Other"])


class SkipList(unittest.TestCase):
    def test_every_case_the_asan_stage_leaves_out_by_coverage_exists(self):
        # A misspelt name in a negative --gtest_filter skips nothing, silently.
        names = case_coverage.cmake_list()
        self.assertGreater(len(names), 0)
        sources = ""
        for name in os.listdir(os.path.join(REPO, "tests")):
            if name.endswith(".cpp"):
                with open(os.path.join(REPO, "tests", name)) as f:
                    sources += f.read()
        for name in names:
            suite, case = name.split(".")
            self.assertRegex(sources, rf"TEST(_F)?\({suite}, {case}\)", name)


if __name__ == "__main__":
    unittest.main()
