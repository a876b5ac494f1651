#!/usr/bin/env python3
"""Object storage: build_bench's 10 M-point LAS built into an S3 store against
into a folder, side by side in one run, with the requests and bytes each way.

A real S3 server, SeaweedFS (`weed mini`, scripts/install-seaweedfs.sh), runs
on loopback in a scratch folder. Three ways, alternated `--reps` times:

  folder  the LAS from the local disk, the set into a folder (the anchor);
  put     the LAS from the local disk, the set published to s3://bench/...;
  s3      the LAS read from the bucket by ranges, the set published to it.

The requests of the s3 way are counted by tests/tools/s3_fault_proxy.py with
no faults, in a run of their own (the proxy is Python: it is not timed).
Prints Markdown for bench/BENCHMARKS.md, "Object storage".

With --stream: stream_bench's four views of the built-in scene streamed by
surfcast-view --headless through surfcast-serve, the set served from a folder
and from the bucket (surfcast-serve s3://..., a fresh server each run), side
by side: time to the first image and to convergence per view.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/store_bench.py [--reps 2] [--threads N] [--stream [--points N]]
"""
import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from build_bench import ROOT, DATA, BIN, tiled_las  # noqa: E402

sys.path.insert(0, os.path.join(ROOT, "tests", "tools"))
from seaweedfs import SeaweedFs, WEED  # noqa: E402

PORT, PROXY = 18433, 18434


def build(args, env, log):
    t0 = time.time()
    out = subprocess.run([os.path.join(BIN, "surfcast-build"), "-q", *args], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True)
    wall = time.time() - t0
    if out.returncode != 0:
        sys.exit(f"surfcast-build {' '.join(args)} failed:\n{out.stdout[-3000:]}")
    log.append(out.stdout)
    return wall, out.stdout


def streaming(a):
    """stream_bench's four views streamed by surfcast-view through surfcast-serve,
    the set served from a folder and from the bucket (a fresh server each run:
    its cache cold), alternated; per view, time to the first image and to
    convergence, best of the runs."""
    from stream_bench import BIN as SBIN, bounds_of, camera_path, json_lines, serve
    import math
    with tempfile.TemporaryDirectory(prefix="store-stream-") as work:
        sets = os.path.join(work, "sets")
        scene = os.path.join(sets, "scene")
        subprocess.run([os.path.join(SBIN, "surfcast-build"), "-q", "--default-scene", "--scene-points", str(a.points), "-o", scene],
                       check=True)
        lo, hi = bounds_of(scene)
        path = os.path.join(work, "path.json")
        json.dump(camera_path(lo, hi, 4, 0.5, 0.9, math.pi), open(path, "w"))
        weed = SeaweedFs(work, PORT, "bench")
        os.environ.update(weed.environment())
        times = {"folder": [], "bucket": []}
        try:
            weed.put_folder(scene, "sets/scene")
            for rep in range(a.reps):
                for way in times:
                    proc, origin = serve(sets if way == "folder" else "s3://bench/sets")
                    try:
                        text = subprocess.run([os.path.join(SBIN, "surfcast-view"), "--headless", f"{origin}/sets/scene", "--lod", "1",
                                               "--size", "960x540", "--camera-path", path, "--out", os.path.join(work, f"{way}.png")],
                                              check=True, capture_output=True, text=True).stdout
                    finally:
                        proc.terminate()
                        proc.wait()
                    lines = json_lines(text)
                    views = []
                    for f in range(4):
                        mine = [l for l in lines if l["frame"] == f]
                        start = 0 if f == 0 else mine[0]["time_s"]
                        first = next((l for l in mine if l["splats"] > 0), mine[-1])
                        views.append((first["time_s"] - start, mine[-1]["time_s"] - start, mine[-1]["bytes_downloaded"]))
                    times[way].append(views)
        finally:
            weed.stop()
    print(f"Machine: {platform.node()}, {os.cpu_count()} cores; the built-in scene at {a.points:,} points; "
          f"{a.reps} runs each way, alternated; best of each.\n")
    # The first view's first image counts from the program's start (opening
    # the set included); later views start with the nodes of the one before.
    ff, fb = (min(r[0][0] for r in times[w]) for w in ("folder", "bucket"))
    print(f"First image of view 0 (from the viewer's start): folder {ff:.2f} s, bucket {fb:.2f} s: **{fb / ff:.2f}×**.\n")
    print("| view | converged, folder (s) | converged, bucket (s) | ratio | MB fetched by then |")
    print("|---|---|---|---|---|")
    for f in range(4):
        cf = min(r[f][1] for r in times["folder"])
        cb = min(r[f][1] for r in times["bucket"])
        mb = times["bucket"][0][f][2] / 1e6
        ratio = f"{cb / cf:.2f}×" if cf >= 0.05 else "(at once)"
        print(f"| {f} | {cf:.2f} | {cb:.2f} | {ratio} | {mb:.1f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--stream", action="store_true", help="streaming through surfcast-serve from the bucket against from a folder")
    ap.add_argument("--points", type=int, default=4_000_000, help="--stream: the built-in scene's points")
    a = ap.parse_args()
    if not os.path.exists(WEED):
        sys.exit(f"{WEED} is missing: scripts/install-seaweedfs.sh builds it")
    if a.stream:
        return streaming(a)
    with tempfile.TemporaryDirectory(prefix="store-bench-") as work:
        las = os.path.join(work, "lion_6x5.las")
        points = tiled_las(os.path.join(DATA, "lion_takanawa.copc.laz"), 6, 5, las)
        weed = SeaweedFs(work, PORT, "bench")
        env = dict(os.environ, **weed.environment())
        try:
            log = []
            common = ["--threads", str(a.threads), "--memory", "2G"]
            weed.put("in/lion_6x5.las", las)
            times = {"folder": [], "put": [], "s3": []}
            published = {}
            for rep in range(a.reps):
                for way in times:
                    out = os.path.join(work, f"set-{way}-{rep}")
                    source = f"s3://bench/in/lion_6x5.las" if way == "s3" else las
                    target = out if way == "folder" else f"s3://bench/sets/{way}-{rep}"
                    wall, stdout = build([source, "-o", target, *common], env, log)
                    times[way].append(wall)
                    m = re.search(r"wrote s3://\S+ \((\d+) objects, (\d+) bytes, (\d+) requests\)", stdout)
                    if m:
                        published[way] = tuple(int(g) for g in m.groups())
            # The s3 way's requests, through the counting proxy.
            counts = os.path.join(work, "counts.json")
            proxy = subprocess.Popen([sys.executable, os.path.join(ROOT, "tests", "tools", "s3_fault_proxy.py"), str(PROXY), str(PORT),
                                      "0", "1", counts], stderr=subprocess.PIPE, text=True)
            proxy.stderr.readline()
            build(["s3://bench/in/lion_6x5.las", "-o", "s3://bench/sets/counted", *common],
                  dict(env, AWS_ENDPOINT_URL=f"http://127.0.0.1:{PROXY}"), log)
            proxy.terminate()
            proxy.wait()
            requests = json.load(open(counts))["forwarded"]
        finally:
            weed.stop()
    best = {way: min(t) for way, t in times.items()}
    las_bytes = points * 36  # LAS 1.4 format 7: 36 bytes a record
    objects, set_bytes, publish_requests = published["s3"]
    print(f"Machine: {platform.node()}, {os.cpu_count()} cores; {points:,} points; {a.reps} runs of each way, alternated; best of each.\n")
    print("| way | best s | runs (s) | speed vs folder |")
    print("|---|---|---|---|")
    for way, label in (("folder", "LAS from disk → folder (anchor)"), ("put", "LAS from disk → s3:// set"),
                       ("s3", "LAS from s3:// → s3:// set")):
        print(f"| {label} | {best[way]:.1f} | {', '.join(f'{t:.1f}' for t in times[way])} | {best['folder'] / best[way]:.2f}× |")
    print(f"\nRequests of the s3 way: {requests} in all, {publish_requests} of them publishing {objects} objects "
          f"({set_bytes:,} bytes); reading the {las_bytes / 2**20:.0f} MiB LAS took the other {requests - publish_requests}.")


if __name__ == "__main__":
    main()
