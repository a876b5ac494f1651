#!/usr/bin/env python3
"""Streaming and level of detail, measured with the real programs.

Streaming: the built-in scene at --points (default 12 M, the largest
set built here in a few minutes) served by surfcast-serve on loopback, and
streamed by surfcast-view --headless URL --lod 1 along a camera path, each
view until converged, every redraw saved (--save-redraws). Per view: time to
the first image (from the program's start, so opening the set counts), time
and bytes until converged; over the path, bytes downloaded against the set's
blocks.bin; PSNR of every redraw against its view's converged image as a
function of the bytes downloaded so far (stream_psnr_bytes.png). Frames per
second at 1280x720 with the default target (1 px): the converged frames'
update (level choice, uploads) plus GPU milliseconds, from the local folder.

Level of detail: a dolly of --frames views towards the set's centre,
rendered converged at the LOD targets 0.5, 1, 2 and 4 px and at full
resolution (every leaf, no LOD). Per target: GPU ms and splats per frame,
PSNR and FLIP against the full-resolution frame, the mean FLIP between
consecutive frames (motion plus popping), and popping itself: the share of
pixels whose error against full resolution jumps by more than 0.1 from one
frame to the next (the motion moves both and cancels). Chart
lod_speed_accuracy.png.

Writes bench/report/stream.csv, lod.csv, the charts and stream.md; prints
the Markdown.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/stream_bench.py [--points 12000000] [--set DIR]
"""
import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from accuracy_bench import metrics, write_csv, write_markdown  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")
REPORT = os.path.join(ROOT, "bench", "report")
TARGETS = [0.5, 1.0, 2.0, 4.0]


def load(png):
    return np.asarray(Image.open(png).convert("RGB")).astype(np.float64) / 255


def json_lines(text):
    return [json.loads(line) for line in text.splitlines() if line.startswith("{")]


def bounds_of(tileset):
    info = json.load(open(os.path.join(tileset, "tileset.json")))
    b = info["bounds"]
    return np.array(b["min"], float), np.array(b["max"], float)


def camera_path(lo, hi, count, height_frac, radius_frac, turn):
    """Eyes on an arc around the set's centre, looking at the centre."""
    centre = (lo + hi) / 2
    extent = hi - lo
    r = radius_frac * max(extent[0], extent[1])
    frames = []
    for k in range(count):
        a = -math.pi / 2 + turn * k / max(1, count - 1)
        eye = centre + np.array([r * math.cos(a), r * math.sin(a), height_frac * extent[2] + 0.1 * r])
        frames.append({"eye": eye.tolist(), "target": centre.tolist(), "up": [0, 0, 1], "fov": 50})
    return {"frames": frames}


def serve(sets_dir):
    proc = subprocess.Popen([os.path.join(BIN, "surfcast-serve"), sets_dir, "--bind", "127.0.0.1:0", "--log", "errors"],
                            stderr=subprocess.PIPE, text=True)
    line = ""
    deadline = time.time() + 30
    while time.time() < deadline:
        line += proc.stderr.readline()
        m = re.search(r"http://127\.0\.0\.1:\d+", line)
        if m:
            return proc, m.group(0)
    proc.kill()
    raise RuntimeError("surfcast-serve did not start: " + line)


def streaming(tileset, name, tmp, size, views):
    lo, hi = bounds_of(tileset)
    path = os.path.join(tmp, "stream_path.json")
    json.dump(camera_path(lo, hi, views, 0.5, 0.9, math.pi), open(path, "w"))
    proc, origin = serve(os.path.dirname(tileset))
    try:
        out = os.path.join(tmp, "stream.png")
        started = time.time()
        text = subprocess.run([os.path.join(BIN, "surfcast-view"), "--headless", f"{origin}/sets/{name}", "--lod", "1",
                               "--size", size, "--camera-path", path, "--save-redraws", "--out", out],
                              check=True, capture_output=True, text=True).stdout
        wall = time.time() - started
    finally:
        proc.terminate()
        proc.wait()
    lines = json_lines(text)
    rows, curve = [], []
    for f in range(views):
        mine = [l for l in lines if l["frame"] == f]
        last = mine[-1]
        final = load(last["redraw"])
        start = mine[0]
        first = next((l for l in mine if l["splats"] > 0), last)
        before = lines[lines.index(start) - 1]["bytes_downloaded"] if f > 0 else 0
        rows.append({"view": f, "first_image_s": first["time_s"] - (0 if f == 0 else start["time_s"]),
                     "converged_s": last["time_s"] - (0 if f == 0 else start["time_s"]),
                     "bytes": last["bytes_downloaded"] - before, "redraws": len(mine), "splats": last["splats"],
                     "nodes": last["nodes"], "converged": last["converged"]})
        for l in mine:
            img = load(l["redraw"])
            psnr = 100.0 if np.array_equal(img, final) else metrics(final, img)[0]
            curve.append({"view": f, "bytes": l["bytes_downloaded"] - before, "time_s": l["time_s"], "psnr": psnr})
    total = os.path.getsize(os.path.join(tileset, "blocks.bin"))
    return rows, curve, total, lines[-1]["bytes_downloaded"], wall


def fps(tileset, tmp, views=5):
    """Converged frames at 1280x720, default target, from the local folder."""
    lo, hi = bounds_of(tileset)
    path = os.path.join(tmp, "fps_path.json")
    json.dump(camera_path(lo, hi, views, 0.5, 0.9, math.pi), open(path, "w"))
    text = subprocess.run([os.path.join(BIN, "surfcast-view"), "--headless", tileset, "--lod", "1", "--size", "1280x720",
                           "--camera-path", path, "--out", os.path.join(tmp, "fps.png")],
                          check=True, capture_output=True, text=True).stdout
    converged = [l for l in json_lines(text) if l["converged"]]
    # A converged view drawn again: one update without uploads, one frame.
    ms = [l["gpu_ms"] + l["update_ms"] for l in converged]
    return {"frames": len(converged), "ms_median": float(np.median(ms)), "gpu_ms_median": float(np.median([l["gpu_ms"] for l in converged])),
            "splats_median": float(np.median([l["splats"] for l in converged]))}


def lod_study(tileset, tmp, size, frames):
    lo, hi = bounds_of(tileset)
    path = os.path.join(tmp, "fly.json")
    # A dolly at walking height towards the centre: nodes cross the targets
    # as they come closer, while the view changes little between frames.
    centre, extent = (lo + hi) / 2, max(hi[0] - lo[0], hi[1] - lo[1])
    dolly = []
    for k in range(frames):
        r = extent * (0.45 - 0.15 * k / max(1, frames - 1))
        dolly.append({"eye": (centre + [0, -r, 0.06 * extent]).tolist(), "target": centre.tolist(), "up": [0, 0, 1],
                      "fov": 50})
    json.dump({"frames": dolly}, open(path, "w"))
    view = os.path.join(BIN, "surfcast-view")

    def images(prefix):
        return [load(os.path.join(tmp, f"{prefix}_{k:04d}.png")) for k in range(frames)]

    text = subprocess.run([view, "--headless", tileset, "--size", size, "--camera-path", path, "--repeat", "1",
                           "--out", os.path.join(tmp, "full.png")], check=True, capture_output=True, text=True).stdout
    full_lines = json_lines(text)
    full = images("full")
    motion = float(np.mean([metrics(full[k], full[k + 1])[2] for k in range(frames - 1)]))
    rows = [{"target": "full", "gpu_ms": float(np.mean([l["gpu_ms"]["total"] for l in full_lines])),
             "splats": float(np.mean([l["splats"] for l in full_lines])), "psnr": float("inf"), "flip": 0.0,
             "consecutive_flip": motion, "popping": 0.0}]  # by definition
    for t in TARGETS:
        prefix = f"lod{t:g}"
        text = subprocess.run([view, "--headless", tileset, "--size", size, "--camera-path", path, "--lod", str(t),
                               "--out", os.path.join(tmp, prefix + ".png")], check=True, capture_output=True, text=True).stdout
        converged = [l for l in json_lines(text) if l["converged"]]
        imgs = images(prefix)
        m = [metrics(full[k], imgs[k]) for k in range(frames)]
        consecutive = float(np.mean([metrics(imgs[k], imgs[k + 1])[2] for k in range(frames - 1)]))
        # Popping: how the error against full resolution changes from frame to
        # frame (the camera's motion moves the full-resolution frame too, and
        # cancels): pixels whose error jumps by more than 0.1 (26 of 255 levels).
        errors = [imgs[k] - full[k] for k in range(frames)]
        jumps = [np.abs(errors[k + 1] - errors[k]).max(axis=2) for k in range(frames - 1)]
        rows.append({"target": t, "gpu_ms": float(np.mean([l["gpu_ms"] for l in converged])),
                     "splats": float(np.mean([l["splats"] for l in converged])),
                     "psnr": float(np.mean([x[0] for x in m])), "flip": float(np.mean([x[2] for x in m])),
                     "consecutive_flip": consecutive, "popping": float(np.mean([(j > 0.1).mean() for j in jumps]))})
    return rows


def charts(curve, lod):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for f in sorted({c["view"] for c in curve}):
        pts = [c for c in curve if c["view"] == f]
        ax.plot([c["bytes"] / 1e6 for c in pts], [min(c["psnr"], 60) for c in pts], marker="o", ms=3,
                label=f"view {f}")
    ax.set_xlabel("MB downloaded for this view")
    ax.set_ylabel("PSNR against the converged image, dB (capped at 60)")
    ax.set_title("Progressive streaming over HTTP (surfcast-serve, loopback, lod 1 px)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(REPORT, "stream_psnr_bytes.png"), dpi=110)

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    sel = [r for r in lod if r["target"] != "full"]
    ax.plot([r["gpu_ms"] for r in sel], [r["flip"] for r in sel], marker="o", label="FLIP against full resolution")
    ax.plot([r["gpu_ms"] for r in sel], [r["popping"] for r in sel], marker="s",
            label="popping: share of pixels whose error jumps > 0.1 between frames")
    for r in sel:
        ax.annotate(f"{r['target']:g} px", (r["gpu_ms"], r["flip"]), textcoords="offset points", xytext=(4, 4), fontsize=8)
    full = [r for r in lod if r["target"] == "full"][0]
    ax.axvline(full["gpu_ms"], color="grey", ls="--", label=f"full resolution ({full['gpu_ms']:.0f} ms)")
    ax.set_xlabel("GPU ms per frame (lavapipe)")
    ax.set_ylabel("mean FLIP; share of pixels")
    ax.set_title("Level-of-detail targets: speed against accuracy and popping")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(REPORT, "lod_speed_accuracy.png"), dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=12_000_000, help="points of the built-in scene")
    ap.add_argument("--set", help="an existing tile set folder instead of building one")
    ap.add_argument("--views", type=int, default=4, help="views on the streaming path")
    ap.add_argument("--frames", type=int, default=12, help="frames of the LOD flythrough")
    ap.add_argument("--size", default="640x360", help="image size of the streaming and LOD studies")
    args = ap.parse_args()
    os.makedirs(REPORT, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tileset = args.set
        if not tileset:
            tileset = os.path.join(tmp, "sets", "scene")
            print(f"building the built-in scene at {args.points} points ...", file=sys.stderr)
            subprocess.run([os.path.join(BIN, "surfcast-build"), "-q", "--default-scene", "--scene-points",
                            str(args.points), "-o", tileset], check=True)
        tileset = os.path.abspath(tileset.rstrip("/"))
        name = os.path.basename(tileset)
        info = json.load(open(os.path.join(tileset, "tileset.json")))
        print("streaming ...", file=sys.stderr)
        rows, curve, total, downloaded, wall = streaming(tileset, name, tmp, args.size, args.views)
        print("frames per second ...", file=sys.stderr)
        rate = fps(tileset, tmp)
        print("level-of-detail study ...", file=sys.stderr)
        lod = lod_study(tileset, tmp, args.size, args.frames)
    write_csv("stream.csv", curve)
    write_csv("lod.csv", lod)
    charts(curve, lod)

    lines = [f"Set: {name}, {info['input_points']} points, {info['surfels']} surfels in {info['nodes']} nodes, "
             f"{info['levels']} levels, {total / 1e6:.1f} MB of blocks" +
             f". Image {args.size}, target 1 px, {args.views} views.", "",
             "| view | first image s | converged s | MB downloaded | redraws | nodes | splats |",
             "|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['view']} | {r['first_image_s']:.2f} | {r['converged_s']:.2f} | {r['bytes'] / 1e6:.2f} | "
                     f"{r['redraws']} | {r['nodes']} | {r['splats']} |")
    lines += ["", f"Downloaded over the path: {downloaded / 1e6:.1f} MB of {total / 1e6:.1f} MB "
                  f"({100 * downloaded / total:.1f}% of blocks.bin), {wall:.1f} s wall.",
              "", f"Converged frames at 1280x720, target 1 px, local folder: median {rate['ms_median']:.0f} ms "
                  f"({1000 / rate['ms_median']:.1f} fps; GPU {rate['gpu_ms_median']:.0f} ms, "
                  f"{rate['splats_median']:.0f} splats) over {rate['frames']} views.",
              "", f"Level of detail, a {args.frames}-frame dolly towards the centre, against full resolution (every leaf):", "",
              "| target px | GPU ms | splats | M splats/s | PSNR dB | FLIP | consecutive FLIP | popping (pixels) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in lod:
        t = r["target"] if r["target"] == "full" else f"{r['target']:g}"
        lines.append(f"| {t} | {r['gpu_ms']:.1f} | {r['splats']:.0f} | {r['splats'] / r['gpu_ms'] / 1e3:.2f} | "
                     f"{r['psnr']:.1f} | {r['flip']:.4f} | {r['consecutive_flip']:.4f} | {100 * r['popping']:.3f}% |")
    write_markdown("stream.md", lines)


if __name__ == "__main__":
    main()
