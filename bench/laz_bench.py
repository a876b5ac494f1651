#!/usr/bin/env python3
"""LAZ decode benchmark: surfcast's reader against laspy + lazrs.

Decodes the same LAZ files with surfcast's reader (the laz crate through
laz_ffi) and with laspy + lazrs, single- and multi-threaded, in the same run.
Files: lone-star.laz (518,862 points, fixed chunks) and a 10.26 M-point LAZ
written by laspy from lion_takanawa.copc.laz tiled 6 x 5. Best of 3 runs each.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/laz_bench.py
"""
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time

import laspy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from build_bench import DATA, ROOT, tiled_las  # noqa: E402

RUNS = 3


def laspy_rate(path, backend):
    best = 0
    for _ in range(RUNS):
        t0 = time.perf_counter()
        las = laspy.read(path, laz_backend=backend)
        n = len(las.points)
        best = max(best, n / (time.perf_counter() - t0))
    return n, best


def surfcast_rate(path, threads):
    best = 0
    binary = os.path.join(ROOT, "build", "bin", "surfcast-read-bench")
    for _ in range(RUNS):
        out = json.loads(subprocess.run([binary, str(threads), path], capture_output=True, text=True, check=True).stdout)
        best = max(best, out["points_per_second"])
    return out["points"], best


def main():
    work = tempfile.mkdtemp(prefix="surfcast-laz-bench-", dir=os.path.join(ROOT, "bench"))
    try:
        las = os.path.join(work, "lion.las")
        tiled_las(os.path.join(DATA, "lion_takanawa.copc.laz"), 6, 5, las)
        big = os.path.join(work, "lion_tiled.laz")
        laspy.read(las).write(big, laz_backend=laspy.LazBackend.LazrsParallel)
        os.remove(las)
        files = [os.path.join(DATA, "lone-star.laz"), big]
        model = re.search(r"model name\s*: (.*)", open("/proc/cpuinfo").read()).group(1)
        print("### LAZ decode, surfcast (laz crate via laz_ffi) against laspy + lazrs\n")
        print(f"- machine: {model}, {os.cpu_count()} cores, {platform.platform()}")
        print(f"- command: `bench/.venv/bin/python bench/laz_bench.py` (best of {RUNS}; laspy {laspy.__version__})\n")
        print("| file | points | decoder | threads | M points/s | vs laspy, same threads |")
        print("|---|---|---|---|---|---|")
        for f in files:
            name = os.path.basename(f)
            n1, ours1 = surfcast_rate(f, 1)
            n2, ours2 = surfcast_rate(f, os.cpu_count())
            m1, theirs1 = laspy_rate(f, laspy.LazBackend.Lazrs)
            m2, theirs2 = laspy_rate(f, laspy.LazBackend.LazrsParallel)
            assert n1 == n2 == m1 == m2, (n1, n2, m1, m2)
            print(f"| {name} | {n1:,} | surfcast | 1 | {ours1 / 1e6:.2f} | {ours1 / theirs1:.2f}x |")
            print(f"| {name} | {n1:,} | laspy + lazrs | 1 | {theirs1 / 1e6:.2f} | 1.00x |")
            print(f"| {name} | {n1:,} | surfcast | {os.cpu_count()} | {ours2 / 1e6:.2f} | {ours2 / theirs2:.2f}x |")
            print(f"| {name} | {n1:,} | laspy + lazrs (parallel) | {os.cpu_count()} | {theirs2 / 1e6:.2f} | 1.00x |")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
