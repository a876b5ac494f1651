#!/usr/bin/env python3
"""Preprocessor throughput benchmark (issue: out-of-core LDC octree tile sets).

Builds a tile set of at least 10 M points from a real scan tiled many times:
lion_takanawa.copc.laz (341,989 points) is decoded with laspy + lazrs, tiled
6 x 5 on a grid in x/y (10.26 M points) and written as one LAS 1.4 file, then
surfcast-build indexes it. Reports input points/s, peak RSS (of the child,
from wait4), bytes per input point and the time per phase, as Markdown.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/build_bench.py
       [--tiles 6x5] [--memory 2G] [--threads N] [--keep]
"""
import argparse
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import laspy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("SURFCAST_DATA_DIR", os.path.join(ROOT, "..", "shared", "data"))


def tiled_las(src, tiles_x, tiles_y, out_path):
    las = laspy.read(src)
    x, y, z = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    # Gap of 10% between copies so tiles stay separate objects.
    dx = (x.max() - x.min()) * 1.1
    dy = (y.max() - y.min()) * 1.1
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = las.header.scales
    header.offsets = las.header.offsets
    n = len(x)
    total = n * tiles_x * tiles_y
    with laspy.open(out_path, mode="w", header=header) as writer:
        for i in range(tiles_x):
            for j in range(tiles_y):
                rec = laspy.ScaleAwarePointRecord.zeros(n, header=header)
                rec.x = x + i * dx
                rec.y = y + j * dy
                rec.z = z
                rec.red, rec.green, rec.blue = las.red, las.green, las.blue
                rec.intensity = las.intensity
                writer.write_points(rec)
    return total


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tiles", default="6x5")
    ap.add_argument("--memory", default="2G")
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--keep", action="store_true", help="keep the generated LAS and tile set")
    args = ap.parse_args()
    tx, ty = (int(v) for v in args.tiles.split("x"))
    binary = os.path.join(ROOT, "build", "bin", "surfcast-build")
    if not os.path.exists(binary):
        sys.exit("build first: scripts/setup.sh")
    work = tempfile.mkdtemp(prefix="surfcast-bench-", dir=os.path.join(ROOT, "bench"))
    try:
        las_path = os.path.join(work, "lion_tiled.las")
        t0 = time.time()
        total = tiled_las(os.path.join(DATA, "lion_takanawa.copc.laz"), tx, ty, las_path)
        print(f"generated {total:,} points in {time.time() - t0:.1f} s ({os.path.getsize(las_path) / 2**20:.0f} MiB LAS)",
              file=sys.stderr)
        out = os.path.join(work, "tileset")
        cmd = [binary, las_path, "-o", out, "--memory", args.memory, "--threads", str(args.threads)]
        t0 = time.time()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        stdout, stderr = proc.communicate()
        wall = time.time() - t0
        rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
        if proc.returncode != 0:
            sys.exit(f"surfcast-build failed:\n{stderr}")
        size = sum(os.path.getsize(os.path.join(out, f)) for f in os.listdir(out))
        phases = re.search(r"^time: (.*)$", stdout, re.M).group(1)
        steps = re.search(r"^build steps \(thread-seconds\): (.*)$", stdout, re.M).group(1)
        cpu = open("/proc/cpuinfo").read()
        model = re.search(r"model name\s*: (.*)", cpu).group(1)
        print(f"### Build throughput, {total / 1e6:.2f} M points ({tx}x{ty} tiles of lion_takanawa)\n")
        print(f"- machine: {model}, {os.cpu_count()} cores, {platform.platform()}")
        print(f"- command: `{' '.join(os.path.relpath(c, ROOT) if c.startswith(ROOT) else c for c in cmd)}`")
        print(f"- input points/s: **{total / wall / 1e6:.3f} M/s** ({wall:.1f} s wall)")
        print(f"- peak RSS: **{rss / 2**20:.0f} MiB** (budget {args.memory})")
        print(f"- output: {size / 2**20:.1f} MiB, **{size / total:.2f} bytes per input point**")
        print(f"- phases: {phases}")
        print(f"- build steps (thread-seconds): {steps}")
        print("\n```\n" + stdout.strip() + "\n```")
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
