#!/usr/bin/env python3
"""The Dask build (scripts/surfcast-dask) against surfcast-build in one
process, side by side on the same inputs: wall time per stage with one worker
process and with two, the work folder's bytes (the shuffle), each task's peak
RSS, and whether the sets are the same bytes. Prints markdown for
bench/BENCHMARKS.md ("A build across processes").

With --store: two workers whose work, inputs and set live in an S3 store
(SeaweedFS on loopback, --work s3://...) against two on a shared folder.

usage: bench/dask_bench.py INPUT... [--memory 2G] [--workers 1,2] [--label NAME]
       bench/dask_bench.py --default-scene --scene-points 300000000 --workers 2
       bench/dask_bench.py INPUT... --store [--reps 2]
"""
import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))
BUILD = os.path.join(REPO, "build", "bin", "surfcast-build")
DRIVER = os.path.join(REPO, "scripts", "surfcast-dask")


def cpu():
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor()


def same(a, b):
    def read(p):
        with open(p, "rb") as f:
            return f.read()
    return all(read(os.path.join(a, n)) == read(os.path.join(b, n)) for n in ("tileset.json", "hierarchy.bin", "blocks.bin"))


def store_runs(args, options, scratch):
    """Two local workers on a shared work folder against two whose work,
    inputs and set live in an S3 store (SeaweedFS on loopback, --work
    s3://...), alternated: wall time and whether the sets are the same bytes."""
    sys.path.insert(0, os.path.join(REPO, "tests", "tools"))
    from seaweedfs import SeaweedFs
    os.makedirs(os.path.join(scratch, "store"))
    store = SeaweedFs(os.path.join(scratch, "store"), 18433, "bench")
    env = dict(os.environ, **store.environment())
    try:
        remote = []
        for o in options:
            if os.path.isfile(o):
                store.put("in/" + os.path.basename(o), o)
                remote.append("s3://bench/in/" + os.path.basename(o))
            else:
                remote.append(o)
        times = {"folder": [], "store": []}
        identical = True
        for rep in range(args.reps):
            for way in times:
                folder = way == "folder"
                work = os.path.join(scratch, f"w{rep}") if folder else f"s3://bench/work/{rep}"
                out = os.path.join(scratch, f"set{rep}") if folder else f"s3://bench/sets/{rep}"
                start = time.monotonic()
                r = subprocess.run([DRIVER, "--local", "2", "-q", "--work", work] + (options if folder else remote) + ["-o", out],
                                   capture_output=True, text=True, env=env)
                if r.returncode:
                    sys.exit(r.stderr)
                times[way].append(time.monotonic() - start)
            for name in ("tileset.json", "hierarchy.bin", "blocks.bin"):
                with open(os.path.join(scratch, f"set{rep}", name), "rb") as f:
                    identical = identical and store.get(f"sets/{rep}/{name}") == f.read()
        # The store's own CPU time: on one machine it shares the workers' cores.
        with open(f"/proc/{store.proc.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        store_cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    finally:
        store.stop()
    best = {way: min(t) for way, t in times.items()}
    print("| work | best s | runs (s) | speed vs shared folder |")
    print("|---|---|---|---|")
    for way, label in (("folder", "2 workers, shared folder (anchor)"), ("store", "2 workers sharing nothing but the store")):
        print(f"| {label} | {best[way]:.1f} | {', '.join(f'{t:.1f}' for t in times[way])} | {best['folder'] / best[way]:.2f}× |")
    print(f"\nSets: {'the same bytes' if identical else 'DIFFERENT'} (tileset.json, hierarchy.bin, blocks.bin).")
    print(f"\nThe store (SeaweedFS, on the same cores) took {store_cpu:.1f} CPU-s over the {args.reps} store runs "
          f"({store_cpu / args.reps:.1f} a run).")
    print(f"\n- command: `bench/dask_bench.py {' '.join(sys.argv[1:])}`")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="*")
    ap.add_argument("--default-scene", action="store_true")
    ap.add_argument("--scene-points", default="1500000")
    ap.add_argument("--memory", default="2G")
    ap.add_argument("--workers", default="1,2", help="worker counts of the Dask runs")
    ap.add_argument("--no-single", action="store_true", help="skip the one-process build")
    ap.add_argument("--label", default="")
    ap.add_argument("--work", default=None, help="scratch folder (default: a temporary one)")
    ap.add_argument("--store", action="store_true",
                    help="two workers sharing nothing but an S3 store (SeaweedFS) against two on a shared folder")
    ap.add_argument("--reps", type=int, default=2, help="--store: runs of each way, alternated")
    args = ap.parse_args()
    inputs = list(args.inputs) + (["--default-scene", "--scene-points", args.scene_points] if args.default_scene else [])
    options = inputs + ["--memory", args.memory]
    scratch = tempfile.mkdtemp(prefix="surfcast-dask-bench-", dir=args.work)
    if args.store:
        try:
            return store_runs(args, options, scratch)
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
    try:
        print(f"- machine: {cpu()}, {os.cpu_count()} cores; {args.label or ' '.join(inputs)}, `--memory {args.memory}`\n")
        rows = []
        single = None
        if not args.no_single:
            out = os.path.join(scratch, "single")
            start = time.monotonic()
            r = subprocess.run([BUILD, "-q"] + options + ["--threads", "2", "-o", out], capture_output=True, text=True)
            if r.returncode:
                sys.exit(r.stderr)
            single = time.monotonic() - start
            rows.append(("surfcast-build, 2 threads", single, None, "", r.stdout))
        for n in [int(w) for w in args.workers.split(",") if w]:
            out, report = os.path.join(scratch, f"dask{n}"), os.path.join(scratch, f"dask{n}.json")
            start = time.monotonic()
            r = subprocess.run([DRIVER, "--local", str(n), "-q", "--report", report, "--work", os.path.join(scratch, f"w{n}")] +
                               options + ["-o", out], capture_output=True, text=True)
            if r.returncode:
                sys.exit(r.stderr)
            wall = time.monotonic() - start
            with open(report) as f:
                rep = json.load(f)
            identical = "not compared" if args.no_single else ("same bytes" if same(out, os.path.join(scratch, "single")) else "DIFFERENT")
            rows.append((f"surfcast-dask, {n} worker{'s' * (n > 1)} x 1 thread", wall, rep, identical, r.stdout))
            shutil.rmtree(out, ignore_errors=True)

        stages = ["scan", "count", "plan", "distribute", "chunk", "merge"]
        print("| build | wall s | " + " | ".join(stages) + " | work folder MB (chunks + nodes) | peak RSS of a task MiB | sets |")
        print("|---|---:|" + "---:|" * len(stages) + "---:|---:|---|")
        for name, wall, rep, identical, _ in rows:
            if rep is None:
                print(f"| {name} | {wall:.1f} | " + " | ".join("" for _ in stages) + " | | | reference |")
                continue
            cells = [f"{rep['stages'][s]['seconds']:.2f}" if s in rep["stages"] else "" for s in stages]
            wb = rep["work_bytes"]
            rss = max(t["rss"] for t in rep["tasks"]) / 2**20
            print(f"| {name} | {wall:.1f} | " + " | ".join(cells) +
                  f" | {wb['chunks'] / 1e6:.0f} + {wb['nodes'] / 1e6:.0f} | {rss:.0f} | {identical} |")
        for name, wall, rep, _, _ in rows:
            if rep:
                speed = f"; speed-up against one process {single / wall:.2f}x" if single else ""
                print(f"\n{name}: {rep['parts']} parts, {sum(1 for t in rep['tasks'] if t['stage'] == 'chunk')} chunk tasks{speed}")
        print(f"\n- command: `bench/dask_bench.py {' '.join(sys.argv[1:])}`")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
