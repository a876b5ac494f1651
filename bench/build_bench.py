#!/usr/bin/env python3
"""Preprocessor benchmark: surfcast-build against PotreeConverter 2, side by side.

Three cases, each run in this one process so that the ratios compare runs on the
same machine at the same time:

1. one big LAS: lion_takanawa.copc.laz (341,989 points) decoded with laspy +
   lazrs and tiled 6 x 5 in x/y into one LAS 1.4 file (10.26 M points, RGB and
   intensity). surfcast-build and PotreeConverter (--method poisson) index it
   with the same thread count; the LAZ of the same points gives the bytes anchor.
2. many small LAZ files: the lion tiled 8 x 8 (21.9 M points) and split by
   tests/tools/split_laz.py into one LAZ file per cell of a 32 x 32 x 8 grid,
   with per-file offsets and cell bounds in the headers, as Potree 1.x and
   Entwine leave a scan. surfcast-build runs at --memory 1G.
3. scale: the built-in scene at 1 M, 10 M and 100 M points (--scale), for time,
   peak RSS and bytes against the point count.

Peak RSS is the child's (wait4). PotreeConverter is built from
../shared/anchors/PotreeConverter by ../shared/tools/build-potreeconverter.sh.
Prints Markdown for bench/BENCHMARKS.md.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/build_bench.py
       [--threads N] [--memory 2G] [--cases single,multi,scale] [--scale 1e6,1e7,1e8] [--keep]
"""
import argparse
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
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("SURFCAST_DATA_DIR", os.path.join(ROOT, "..", "shared", "data"))
BIN = os.path.join(ROOT, "build", "bin")


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


def run_measured(cmd):
    """Runs cmd as a child of a fresh fork so that its own peak RSS is read."""
    t0 = time.time()
    pid = os.fork()
    if pid == 0:
        devnull = os.open(os.devnull, os.O_WRONLY)
        out = os.open(run_measured.log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(out, 1)
        os.dup2(devnull, 2)
        try:
            os.execv(cmd[0], cmd)
        finally:
            os._exit(127)
    _, status, usage = os.wait4(pid, 0)
    wall = time.time() - t0
    stdout = open(run_measured.log).read()
    if not os.WIFEXITED(status) or os.WEXITSTATUS(status) != 0:
        sys.exit(f"{' '.join(cmd)} failed ({status}):\n{stdout[-4000:]}")
    return wall, usage.ru_maxrss * 1024, stdout


def folder_bytes(path):
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files)


def potree_binary():
    script = os.path.join(ROOT, "..", "shared", "tools", "build-potreeconverter.sh")
    out = subprocess.run(["bash", script], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, check=True)
    return out.stdout.strip().splitlines()[-1]


def surfcast(inputs, out, memory, threads, extra=()):
    cmd = [os.path.join(BIN, "surfcast-build"), "-q", *inputs, "-o", out, "--memory", memory, "--threads", str(threads), *extra]
    wall, rss, stdout = run_measured(cmd)
    phases = re.search(r"^time: (.*)$", stdout, re.M).group(1)
    steps = re.search(r"^build steps \(thread-seconds\): (.*)$", stdout, re.M).group(1)
    return {"wall": wall, "rss": rss, "bytes": folder_bytes(out), "phases": phases, "steps": steps, "cmd": cmd}


def potree(binary, inputs, out):
    cmd = [binary, *inputs, "-o", out, "--method", "poisson"]
    wall, rss, _ = run_measured(cmd)
    return {"wall": wall, "rss": rss, "bytes": folder_bytes(out), "cmd": cmd}


def rel(cmd, work):
    return " ".join(c.replace(work, "WORK").replace(ROOT + "/", "") for c in cmd)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--memory", default="2G")
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--cases", default="single,multi,scale", help="which of the three cases to run")
    ap.add_argument("--scale", default="1e6,1e7,1e8", help="built-in scene sizes for the scaling case ('' for none)")
    ap.add_argument("--keep", action="store_true", help="keep the generated inputs and tile sets")
    args = ap.parse_args()
    if not os.path.exists(os.path.join(BIN, "surfcast-build")):
        sys.exit("build first: scripts/setup.sh")
    pc = potree_binary()
    work = tempfile.mkdtemp(prefix="surfcast-bench-", dir=os.path.join(ROOT, "bench"))
    run_measured.log = os.path.join(work, "stdout.txt")
    cpu = open("/proc/cpuinfo").read()
    model = re.search(r"model name\s*: (.*)", cpu).group(1)
    print(f"- machine: {model}, {os.cpu_count()} cores, {platform.platform()}; {args.threads} threads for both")
    try:
        cases = args.cases.split(",")
        # 1. One big LAS.
        if "single" in cases:
            las_path = os.path.join(work, "lion_tiled.las")
            total = tiled_las(os.path.join(DATA, "lion_takanawa.copc.laz"), 6, 5, las_path)
            laz_path = os.path.join(work, "lion_tiled.laz")
            laspy.read(las_path).write(laz_path)
            laz_bpp = os.path.getsize(laz_path) / total
            s = surfcast([las_path], os.path.join(work, "sc"), args.memory, args.threads)
            p = potree(pc, [las_path], os.path.join(work, "pc"))
            print(f"\n### One LAS, {total:,} points (lion_takanawa tiled 6 x 5)\n")
            print("| | wall s | peak RSS MiB | bytes/point | speed ratio (PotreeConverter / surfcast) |")
            print("|---|---:|---:|---:|---:|")
            print(f"| surfcast-build | {s['wall']:.1f} | {s['rss'] / 2**20:.0f} | {s['bytes'] / total:.2f} "
                  f"({s['bytes'] / total / laz_bpp:.2f}x LAZ) | **{p['wall'] / s['wall']:.3f}** |")
            print(f"| PotreeConverter 2 (poisson) | {p['wall']:.1f} | {p['rss'] / 2**20:.0f} | {p['bytes'] / total:.2f} (uncompressed) | 1 |")
            print(f"| LAZ (laspy + lazrs) | | | {laz_bpp:.2f} | |")
            print(f"\n- surfcast: `{rel(s['cmd'], work)}`; phases: {s['phases']}; steps (thread-seconds): {s['steps']}")
            print(f"- PotreeConverter: `{rel(p['cmd'], work)}`")

        # 2. Many small LAZ files.
        if "multi" in cases:
            tiles = os.path.join(work, "tiles")
            out = subprocess.run([sys.executable, os.path.join(ROOT, "tests", "tools", "split_laz.py"),
                                  os.path.join(DATA, "lion_takanawa.copc.laz"), tiles, "--tiles", "8x8", "--cells", "32x32x8"],
                                 stdout=subprocess.PIPE, text=True, check=True)
            made = json.loads(out.stdout.strip().splitlines()[-1])
            s = surfcast([tiles], os.path.join(work, "sc-multi"), "1G", args.threads)
            files = sorted(os.path.join(tiles, f) for f in os.listdir(tiles))
            p = potree(pc, files, os.path.join(work, "pc-multi"))
            laz_bytes = folder_bytes(tiles)
            n = made["points"]
            print(f"\n### {made['files']:,} small LAZ files, {n:,} points (lion tiled 8 x 8, one file per cell of 32 x 32 x 8)\n")
            print("| | wall s | peak RSS MiB | bytes/point | speed ratio |")
            print("|---|---:|---:|---:|---:|")
            print(f"| surfcast-build --memory 1G | {s['wall']:.1f} | {s['rss'] / 2**20:.0f} | {s['bytes'] / n:.2f} | **{p['wall'] / s['wall']:.3f}** |")
            print(f"| PotreeConverter 2 (poisson) | {p['wall']:.1f} | {p['rss'] / 2**20:.0f} | {p['bytes'] / n:.2f} (uncompressed) | 1 |")
            print(f"| the input LAZ files | | | {laz_bytes / n:.2f} | |")
            print(f"\n- surfcast: `{rel(s['cmd'], work)}`; phases: {s['phases']}; steps: {s['steps']}")

        # 3. Scale.
        sizes = [int(float(v)) for v in args.scale.split(",") if v] if "scale" in cases else []
        if sizes:
            print("\n### Scale: the built-in scene\n")
            print("| points | wall s | M points/s | peak RSS MiB (budget) | bytes/point | chunks |")
            print("|---:|---:|---:|---:|---:|---:|")
            for n in sizes:
                out = os.path.join(work, f"scene-{n}")
                s = surfcast(["--default-scene", "--scene-points", str(n)], out, args.memory, args.threads)
                info = subprocess.run([os.path.join(BIN, "surfcast-build"), "--info", out], stdout=subprocess.PIPE, text=True).stdout
                points = int(re.search(r"(\d+) input points", info).group(1))
                chunks = re.search(r"(\d+) chunks", open(run_measured.log).read())
                print(f"| {points:,} | {s['wall']:.1f} | {points / s['wall'] / 1e6:.2f} | {s['rss'] / 2**20:.0f} ({args.memory}) | "
                      f"{s['bytes'] / points:.2f} | {chunks.group(1) if chunks else '?'} |", flush=True)
                shutil.rmtree(out, ignore_errors=True)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
