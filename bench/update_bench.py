#!/usr/bin/env python3
"""Updates in place against a rebuild, side by side (README, "Updating a set").

The lion (lion_takanawa.copc.laz) tiled --tiles in x/y and cut into --cells
files of about a million points each by tests/tools/split_laz.py: a survey of
many files. The set of all files but one inner cell is built once; then, in
this one process, one after the other:

  update   a copy of that set, `surfcast-build --add CELL --to SET`;
  rebuild  `surfcast-build` of every file, the cell included.

For each: wall time, bytes written (the update: what it appended to
blocks.bin, its hierarchy, build record and tileset.json; the rebuild: the
whole set), and the bytes a client holding the old set must fetch again: the
nodes whose block is not where and what it was (byte ranges of blocks.bin),
and the nodes whose block bytes changed (surfcast-serve's node ETags are the
block's CRC and size), each with the new hierarchy and tileset.json.

With --repeated N: the lion tiled 6 x 5 (10.26 M points) cut into 32 x 32
cells of about 0.1 % each; the set of all cells but N, then those N added one
update at a time. Against a fresh build of all the cells and the updated set
compacted (--compact): blocks.bin's bytes, the live blocks' bytes (what a
client streaming the whole set downloads), time, and the images of four
views at --lod 1 against the fresh build's (mean FLIP, flip-evaluator).

With --store: the same update of the base set uploaded to an S3 store
(SeaweedFS on loopback), against the folder update and a rebuild published
to the store: time, bytes written, requests.

With --dask N: the same update of a copy of the base set in one process and
through scripts/surfcast-dask on a local cluster of N workers (the update's
stages as tasks), side by side: wall time, and whether every file of the two
sets is the same bytes (no rebuild).

With --follow S: a copy of the base set served by surfcast-serve, a
headless viewer following it (surfcast-view --lod 1 --follow S, the set
framed at 640x360) converged on it, then the same --add: the time from the
update's end to the follower's first converged frame of the new version, the
bytes the follower fetched for it against the changed nodes' bytes and a
fresh open's, and whether its last image is a fresh open's, byte for byte.

Usage: bench/.venv/bin/python bench/update_bench.py [--tiles 18x17] [--cells 10x10x1]
       [--work DIR] [--threads N] [--memory 2G] [--repeated N | --dask N | --store | --follow S]
Prints Markdown for bench/BENCHMARKS.md ("Updates in place").
"""
import argparse
import json
import os
import platform
import shutil
import struct
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("SURFCAST_DATA_DIR", os.path.join(ROOT, "..", "shared", "data"))
BUILD = os.path.join(ROOT, "build", "bin", "surfcast-build")


def records(set_dir):
    """{(level, x, y, z): (offset, size, crc)} of a set's hierarchy."""
    info = json.load(open(os.path.join(set_dir, "tileset.json")))
    data = open(os.path.join(set_dir, info["hierarchy"].get("file", "hierarchy.bin")), "rb").read()
    pages = struct.unpack_from("<I", data, 12)[0]
    out = {}
    for p in range(pages):
        offset, count, _ = struct.unpack_from("<QII", data, 32 + 16 * p)
        for i in range(count):
            level, _, _, x, y, z, block, size, crc = struct.unpack_from("<BBHIIIQII", data, offset + 64 * i)
            out[(level, x, y, z)] = (block, size, crc)
    return out, len(data), info


def run(args):
    start = time.monotonic()
    r = subprocess.run(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        sys.exit(f"{' '.join(args[:3])}...: exit {r.returncode}\n{r.stdout[-3000:]}")
    return time.monotonic() - start, r.stdout


def set_bytes(set_dir):
    return sum(os.path.getsize(os.path.join(set_dir, f)) for f in os.listdir(set_dir))


def live_bytes(set_dir):
    return sum(size for _, size, _ in records(set_dir)[0].values())


def views(set_dir, out_prefix):
    """Four views around the set at --lod 1, as float images in [0, 1]."""
    import numpy as np
    from PIL import Image
    info = json.load(open(os.path.join(set_dir, "tileset.json")))
    lo, hi = info["bounds"]["min"], info["bounds"]["max"]
    centre = [(a + b) / 2 for a, b in zip(lo, hi)]
    radius = max(b - a for a, b in zip(lo, hi))
    images = []
    for i, (dx, dy) in enumerate(((1, 0), (0, 1), (-1, 0), (0, -1))):
        eye = [centre[0] + dx * radius, centre[1] + dy * radius, centre[2] + 0.6 * radius]
        camera = ",".join(str(v) for v in eye + centre + [0, 0, 1, 45])
        png = f"{out_prefix}_{i}.png"
        subprocess.run([os.path.join(ROOT, "build", "bin", "surfcast-view"), "--headless", set_dir, "--size", "640x360",
                        "--lod", "1", f"--camera={camera}", "--out", png], check=True, capture_output=True)
        images.append(np.asarray(Image.open(png).convert("RGB")).astype(np.float32) / 255)
    return images


def repeated(a):
    import flip_evaluator as flip
    work = os.path.join(a.work, "repeated")
    os.makedirs(work, exist_ok=True)
    cells = os.path.join(work, "cells")
    if not os.path.isdir(cells):
        run([sys.executable, os.path.join(ROOT, "tests", "tools", "split_laz.py"), os.path.join(DATA, "lion_takanawa.copc.laz"),
             cells, "--tiles", "6x5", "--cells", "32x32x1", "--min-files", "200"])
    files = sorted(os.path.join(cells, f) for f in os.listdir(cells))
    step = len(files) // a.repeated
    adds = files[step // 2::step][:a.repeated]
    base = [f for f in files if f not in adds]
    for name, inputs in (("base.list", base), ("all.list", base + adds)):
        with open(os.path.join(work, name), "w") as f:
            f.write("\n".join(inputs) + "\n")
    common = ["-q", "--threads", a.threads, "--memory", a.memory]
    upd, fresh = os.path.join(work, "update"), os.path.join(work, "rebuild")
    shutil.rmtree(upd, ignore_errors=True)
    t_base, _ = run([BUILD, *common, "@" + os.path.join(work, "base.list"), "-o", upd])
    base_bytes = os.path.getsize(os.path.join(upd, "blocks.bin"))
    times = []
    for f in adds:
        t, _ = run([BUILD, "-q", "--threads", a.threads, "--add", f, "--to", upd])
        times.append(t)
    shutil.rmtree(fresh, ignore_errors=True)
    t_fresh, _ = run([BUILD, *common, "@" + os.path.join(work, "all.list"), "-o", fresh])
    updated_blocks, updated_live = os.path.getsize(os.path.join(upd, "blocks.bin")), live_bytes(upd)
    ref = views(fresh, os.path.join(work, "fresh"))
    img = views(upd, os.path.join(work, "updated"))
    flips = [float(flip.evaluate(r, i, "LDR")[1]) for r, i in zip(ref, img)]
    compacted = os.path.join(work, "compacted")
    shutil.rmtree(compacted, ignore_errors=True)
    shutil.copytree(upd, compacted)
    t_compact, _ = run([BUILD, "--compact", compacted])
    points = json.load(open(os.path.join(fresh, "tileset.json")))["input_points"]
    print(f"\nRepeated appends: {len(adds)} updates of one cell each ({points / len(files):,.0f} points, "
          f"{100 / len(files):.2f} % of {points:,}), to the set of the other {len(base)} cells (built in {t_base:.1f} s)\n")
    print("| set | blocks.bin | live blocks (a whole-set download) | nodes | time (s) |")
    print("|---|---|---|---|---|")
    print(f"| fresh build of all cells | {os.path.getsize(os.path.join(fresh, 'blocks.bin')):,} | {live_bytes(fresh):,} | "
          f"{len(records(fresh)[0]):,} | {t_fresh:.1f} |")
    print(f"| after {len(adds)} updates | {updated_blocks:,} (base {base_bytes:,}) | {updated_live:,} | {len(records(upd)[0]):,} | "
          f"{sum(times):.1f} in all, {min(times):.2f}-{max(times):.2f} each |")
    print(f"| compacted | {os.path.getsize(os.path.join(compacted, 'blocks.bin')):,} | {live_bytes(compacted):,} | "
          f"{len(records(compacted)[0]):,} | {t_compact:.1f} |")
    print(f"\nMean FLIP of the updated set against the fresh build at --lod 1, four views: "
          f"{', '.join(f'{v:.4f}' for v in flips)} (compaction moves no byte of a block)")


def dask_update(a, base_set, upd, added, t_update):
    """The update just made in one process (`upd`), made again through the
    Dask driver on a copy of the base set at the same path (the build record
    names it): time side by side, and the two sets' bytes compared."""
    one = upd + ".one-process"
    shutil.rmtree(one, ignore_errors=True)
    os.rename(upd, one)
    shutil.copytree(base_set, upd)
    report = os.path.join(a.work, "dask-update.json")
    t_dask, out = run([os.path.join(ROOT, "scripts", "surfcast-dask"), "--local", str(a.dask), "-q", "--report", report,
                       "--add", added, "--to", upd])
    same = sorted(os.listdir(one)) == sorted(os.listdir(upd)) and all(
        open(os.path.join(one, f), "rb").read() == open(os.path.join(upd, f), "rb").read() for f in os.listdir(one))
    stages = json.load(open(report))["stages"]
    print(f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; `{' '.join(sys.argv)}`\n")
    print("| update | time (s) | stages (tasks, s) | same bytes |")
    print("|---|---|---|---|")
    print(f"| one process (--threads {a.threads}) | {t_update:.1f} | | |")
    print(f"| surfcast-dask, {a.dask} workers | {t_dask:.1f} | " +
          ", ".join(f"{k} {v['tasks']}, {v['seconds']:.1f}" for k, v in stages.items()) + f" | {'yes' if same else 'NO'} |")
    shutil.rmtree(one, ignore_errors=True)


def store_update(a, base_set, added, all_list, t_update):
    """The same update of the base set in an S3 store (SeaweedFS on loopback,
    as bench/store_bench.py runs it): the set uploaded as `aws s3 sync`
    would, then `--add CELL --to s3://...` and a rebuild published to the
    store, side by side with the folder update just made: time, bytes
    written and requests."""
    import re
    sys.path.insert(0, os.path.join(ROOT, "tests", "tools"))
    from seaweedfs import SeaweedFs
    store_dir = os.path.join(a.work, "store")
    shutil.rmtree(store_dir, ignore_errors=True)
    os.makedirs(store_dir)
    weed = SeaweedFs(store_dir, 18433, "bench")
    env = dict(os.environ, **weed.environment())

    def timed(args):
        start = time.monotonic()
        r = subprocess.run(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if r.returncode != 0:
            sys.exit(f"{' '.join(args[:3])}...: exit {r.returncode}\n{r.stdout[-3000:]}")
        return time.monotonic() - start, r.stdout

    try:
        weed.put_folder(base_set, "sets/base")
        t_store, out = timed([BUILD, "-q", "--threads", a.threads, "--add", added, "--to", "s3://bench/sets/base"])
        m = re.search(r"published \S+: (\d+) objects, (\d+) bytes, (\d+) requests; (\d+) objects", out)
        objects, written, requests, removed = (int(g) for g in m.groups())
        t_rebuild, out = timed([BUILD, "-q", "--threads", a.threads, "--memory", a.memory, "@" + all_list, "-o", "s3://bench/sets/rebuild"])
        m = re.search(r"wrote s3://\S+ \((\d+) objects, (\d+) bytes, (\d+) requests\)", out)
        r_objects, r_written, r_requests = (int(g) for g in m.groups())
    finally:
        weed.stop()
    print(f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; `{' '.join(sys.argv)}`\n")
    print("| | time (s) | bytes written | objects written | requests |")
    print("|---|---|---|---|---|")
    print(f"| update of the folder set (anchor) | {t_update:.1f} | | | |")
    print(f"| update of the set in the store | {t_store:.1f} | {written:,} | {objects} (+{removed} deleted) | {requests} publishing |")
    print(f"| rebuild into the store | {t_rebuild:.1f} | {r_written:,} | {r_objects} | {r_requests} publishing |")
    print(f"\nThe store update: {100 * t_store / t_rebuild:.1f} % of the rebuild's time, {100 * written / r_written:.1f} % of its bytes; "
          f"{t_update / t_store:.2f}x the speed of the folder update.")


def follow_update(a, base_set, added):
    """A headless follower of the served set through the --add (--follow)."""
    import queue
    import re
    import threading
    view = os.path.join(ROOT, "build", "bin", "surfcast-view")
    sets = os.path.join(a.work, "follow")
    served = os.path.join(sets, "site")
    shutil.rmtree(sets, ignore_errors=True)
    os.makedirs(sets)
    shutil.copytree(base_set, served)
    server = subprocess.Popen([os.path.join(ROOT, "build", "bin", "surfcast-serve"), sets, "--bind", "127.0.0.1:0"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        origin = None
        while origin is None:
            line = server.stderr.readline()
            if not line:
                sys.exit("surfcast-serve did not start")
            m = re.search(r"(http://127\.0\.0\.1:\d+)", line)
            origin = m.group(1) if m else None
        url = origin + "/sets/site"
        follower = subprocess.Popen([view, "--headless", url, "--lod", "1", "--size", "640x360", "--follow", str(a.follow),
                                     "--max-wait", "600", "--save-redraws", "--out", os.path.join(a.work, "follow.png")],
                                    stdout=subprocess.PIPE, text=True)
        lines = queue.Queue()
        threading.Thread(target=lambda: [lines.put((time.monotonic(), json.loads(l))) for l in follower.stdout],
                         daemon=True).start()

        log = open(os.path.join(a.work, "follow.jsonl"), "w")

        def until(done):
            while True:
                t, line = lines.get(timeout=600)
                log.write(json.dumps(line) + "\n")
                if done(line):
                    return t, line
        until(lambda l: l["converged"])
        old, _, _ = records(served)
        t_update, _ = run([BUILD, "-q", "--threads", a.threads, "--add", added, "--to", served])
        switched = time.monotonic()
        t_seen, seen = until(lambda l: l["version"] == 1 and l["converged"])
        follower.terminate()
        follower.wait()
        new, hierarchy_bytes, _ = records(served)
        changed = sum(s for k, (o, s, c) in new.items() if k not in old or old[k][1:] != (s, c))
        fresh_png = os.path.join(a.work, "fresh.png")
        _, out = run([view, "--headless", url, "--lod", "1", "--size", "640x360", "--out", fresh_png])
        fresh = json.loads(out.strip().splitlines()[-1])
        same = open(seen["redraw"], "rb").read() == open(fresh_png, "rb").read()
    finally:
        server.terminate()
        server.wait()
    print(f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; `{' '.join(sys.argv)}`\n")
    print("| | seconds / bytes |\n|---|---|")
    print(f"| the update (--add, in place) | {t_update:.1f} s |")
    render = seen["gpu_ms"] / 1e3
    print(f"| its end to the follower's switch to the new version, converged | {t_seen - switched - render:.2f} s "
          f"(polling every {a.follow} s) |")
    print(f"| the same to that frame's image (lavapipe's render of it: {render:.2f} s) | {t_seen - switched:.2f} s |")
    print(f"| blocks the follower fetched for the new version | {seen['bytes_downloaded']:,} "
          f"({seen['adopted']:,} nodes taken from the old version, {seen['shared']:,} of them drawn from its GPU copies) |")
    print(f"| blocks of every node the update changed | {changed:,} |")
    print(f"| blocks a fresh open of the new version fetches for the same view | {fresh['bytes_downloaded']:,} |")
    print(f"| the follower's last image is a fresh open's, byte for byte | {'yes' if same else 'no'} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tiles", default="18x17")
    ap.add_argument("--cells", default="10x10x1")
    ap.add_argument("--work", default="/tmp/surfcast-update-bench")
    ap.add_argument("--threads", default=str(os.cpu_count()))
    ap.add_argument("--memory", default="2G")
    ap.add_argument("--repeated", type=int, default=0, help="appends of one 0.1 %% cell each (the drift case)")
    ap.add_argument("--dask", type=int, default=0, help="the update in one process against surfcast-dask on N local workers")
    ap.add_argument("--store", action="store_true", help="the update of the set in an S3 store (SeaweedFS) against in a folder")
    ap.add_argument("--follow", type=float, default=0, help="a headless viewer polling every S seconds follows the update")
    a = ap.parse_args()
    if a.repeated:
        return repeated(a)
    os.makedirs(a.work, exist_ok=True)
    cells = os.path.join(a.work, "cells")
    if not os.path.isdir(cells):
        run([sys.executable, os.path.join(ROOT, "tests", "tools", "split_laz.py"), os.path.join(DATA, "lion_takanawa.copc.laz"),
             cells, "--tiles", a.tiles, "--cells", a.cells, "--min-files", "10"])
    files = sorted(os.path.join(cells, f) for f in os.listdir(cells))
    # The middle cell (split_laz.py names a cell's file by its index
    # (x * cells_y + y) * cells_z + z): an inner one.
    cx, cy, cz = (int(v) for v in a.cells.split("x"))
    added = os.path.join(cells, "r%06d.laz" % ((cx // 2 * cy + cy // 2) * cz))
    if added not in files:
        sys.exit(f"{added}: the middle cell holds no points; choose other --cells")
    base = [f for f in files if f != added]
    common = ["-q", "--threads", a.threads, "--memory", a.memory]
    with open(os.path.join(a.work, "base.list"), "w") as f:
        f.write("\n".join(base) + "\n")
    with open(os.path.join(a.work, "all.list"), "w") as f:
        f.write("\n".join(base + [added]) + "\n")
    base_set, upd, fresh = (os.path.join(a.work, n) for n in ("base", "update", "rebuild"))
    if not os.path.exists(os.path.join(base_set, "tileset.json")):
        t, _ = run([BUILD, *common, "@" + os.path.join(a.work, "base.list"), "-o", base_set])
        print(f"base set built in {t:.1f} s", file=sys.stderr)
    if a.follow:
        return follow_update(a, base_set, added)
    old, _, old_info = records(base_set)
    shutil.rmtree(upd, ignore_errors=True)
    shutil.copytree(base_set, upd)

    t_update, out_update = run([BUILD, "-q", "--threads", a.threads, "--add", added, "--to", upd])
    if a.dask:
        return dask_update(a, base_set, upd, added, t_update)
    if a.store:
        return store_update(a, base_set, added, os.path.join(a.work, "all.list"), t_update)
    shutil.rmtree(fresh, ignore_errors=True)
    t_rebuild, _ = run([BUILD, *common, "@" + os.path.join(a.work, "all.list"), "-o", fresh])

    rows = []
    for name, folder, seconds in (("update", upd, t_update), ("rebuild", fresh, t_rebuild)):
        new, hierarchy_bytes, info = records(folder)
        json_bytes = os.path.getsize(os.path.join(folder, "tileset.json"))
        if name == "update":
            record = os.path.join(folder, "build" + info["hierarchy"]["file"][len("hierarchy"):])
            written = info["blocks"]["bytes"] - old_info["blocks"]["bytes"] + hierarchy_bytes + os.path.getsize(record) + json_bytes
        else:
            written = set_bytes(folder)
        by_range = sum(s for k, (o, s, c) in new.items() if old.get(k) != (o, s, c))
        by_crc = sum(s for k, (o, s, c) in new.items() if k not in old or old[k][1:] != (s, c))
        kept = sum(1 for k, r in new.items() if old.get(k) == r)
        rows.append((name, seconds, written, by_range + hierarchy_bytes + json_bytes, by_crc + hierarchy_bytes + json_bytes,
                     len(new), kept, info["blocks"]["bytes"], info["input_points"]))
    added_points = rows[0][8] - old_info["input_points"]
    print(f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"`{' '.join(sys.argv)}`\n")
    print(f"Set: {old_info['input_points']:,} points in {len(base)} files; added: {os.path.basename(added)}, "
          f"{added_points:,} points ({100 * added_points / old_info['input_points']:.2f} %)\n")
    print("| | time (s) | bytes written | re-download, byte ranges | re-download, node ETags | nodes | nodes kept in place | blocks.bin |")
    print("|---|---|---|---|---|---|---|---|")
    for name, seconds, written, by_range, by_crc, nodes, kept, blocks, _ in rows:
        print(f"| {name} | {seconds:.1f} | {written:,} | {by_range:,} | {by_crc:,} | {nodes:,} | {kept:,} | {blocks:,} |")
    u, r = rows
    print(f"\nupdate / rebuild: time {u[1] / r[1]:.3f}, bytes written {u[2] / r[2]:.3f}, "
          f"re-download by ranges {u[3] / r[3]:.3f}, by ETags {u[4] / r[4]:.3f}")
    print("\nupdate's summary:\n```\n" + out_update.strip() + "\n```")


if __name__ == "__main__":
    main()
