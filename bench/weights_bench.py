#!/usr/bin/env python3
"""Normalization weights: capture by rendering (Ren 2002 §7.2) against the
analytic sum, measured.

For each model (the shared scans bunny, horse, igea, and a synthetic jittered
plane with a boundary) it builds a tile set with analytic weights (timed, and
once more with --weights none: the difference is the analytic weights' cost),
copies it and captures weights with surfcast-weights (timed). Then it renders
every leaf with ewa-pixel and ewa-surfel at a magnified and a minified view, in
one uniform colour (0.4, unlit, black background), and once more minified with
level 0 (the coarsest, closest to what level selection would draw), and compares: per-pixel
normalization gives exactly 0.4 wherever it covers, so the per-surfel render's
brightness error is |S / 0.4 - 1| per pixel (1 where it leaves a hole).
Pixels within 8 px of the per-pixel render's outline are "edge", the rest
"interior". Writes bench/report/weights.csv and weights.png, prints Markdown.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/weights_bench.py [--views 32]
"""
import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")
DATA = os.environ.get("SURFCAST_DATA_DIR", os.path.join(ROOT, "..", "shared", "data"))
REPORT = os.path.join(ROOT, "bench", "report")
GREY = 0.4
SIZE = (480, 360)
# The edge band: about a splat radius in the magnified views (r sqrt(2c) of
# 2-9 px there); the fringe where per-surfel weights fall short lies in it.
BAND = 8


def run(args):
    t = time.time()
    out = subprocess.run(args, check=True, capture_output=True, text=True)
    return time.time() - t, out.stdout


def synthetic_plane(path, n=250, jitter=0.4, seed=1):
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    x = i.ravel() + rng.uniform(-jitter, jitter, n * n)
    y = j.ravel() + rng.uniform(-jitter, jitter, n * n)
    pts = np.column_stack([x, y, np.zeros(n * n), np.zeros(n * n), np.zeros(n * n), np.ones(n * n)])
    np.savetxt(path, pts, fmt="%.5f")


def cameras(tileset):
    info = json.load(open(os.path.join(tileset, "tileset.json")))
    lo, hi = np.array(info["bounds"]["min"]), np.array(info["bounds"]["max"])
    centre, diag = (lo + hi) / 2, np.linalg.norm(hi - lo)
    d = np.array([0.3, -0.6, 1.0])
    d /= np.linalg.norm(d)
    up = "0,0,1" if abs(d[2]) < 0.99 else "0,1,0"
    out = {}
    for name, dist, level in [("magnified", 0.45 * diag, "leaves"), ("minified", 5.0 * diag, "leaves"),
                              ("minified-level0", 5.0 * diag, "0")]:
        eye = centre + d * dist
        out[name] = (",".join(f"{v:.9g}" for v in [*eye, *centre]) + "," + up + ",40", level)
    return out


def render(tileset, mode, camera, png):
    camera, level = camera
    run([os.path.join(BIN, "surfcast-view"), "--headless", tileset, f"--camera={camera}", "--level", level, "--size",
         f"{SIZE[0]}x{SIZE[1]}", "--mode", mode, "--color", f"{GREY},{GREY},{GREY}", "--shading", "unlit",
         "--background", "0,0,0", "--out", png])
    return np.asarray(Image.open(png).convert("RGB")).astype(float)


def errors(pixel, surfel):
    covered = pixel.max(axis=2) > 0
    # Edge: covered pixels within BAND px of an uncovered one (or of the border).
    inner = covered.copy()
    for _ in range(BAND):
        shrunk = inner.copy()
        shrunk[1:, :] &= inner[:-1, :]
        shrunk[:-1, :] &= inner[1:, :]
        shrunk[:, 1:] &= inner[:, :-1]
        shrunk[:, :-1] &= inner[:, 1:]
        shrunk[0, :] = shrunk[-1, :] = False
        shrunk[:, 0] = shrunk[:, -1] = False
        inner = shrunk
    edge = covered & ~inner
    err = np.abs(surfel[..., 1] / (pixel[..., 1] + 1e-9) - 1.0)
    out = {}
    for region, mask in [("interior", inner), ("edge", edge)]:
        e = err[mask]
        out[region] = (float(e.mean()) if e.size else float("nan"), float(np.percentile(e, 99)) if e.size else float("nan"),
                       int(e.size))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, default=32)
    ap.add_argument("--models", default="plane,bunny,horse,igea")
    ap.add_argument("--chart-only", action="store_true", help="redraw weights.png from weights.csv")
    args = ap.parse_args()
    if args.chart_only:
        with open(os.path.join(REPORT, "weights.csv")) as f:
            rows = [(r[0], r[1], r[2], r[3], float(r[4]), float(r[5]), int(r[6])) for r in list(csv.reader(f))[1:]]
        chart(rows)
        return
    os.makedirs(REPORT, exist_ok=True)
    rows, times = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for model in args.models.split(","):
            if model == "plane":
                src = os.path.join(tmp, "plane.xyz")
                synthetic_plane(src)
                extra = ["--columns", "x,y,z,nx,ny,nz"]
            else:
                src = os.path.join(DATA, model + ".ply")
                extra = []
            analytic = os.path.join(tmp, model + "_analytic")
            t_none, _ = run([os.path.join(BIN, "surfcast-build"), "-q", src, *extra, "--weights", "none", "-o",
                             os.path.join(tmp, model + "_none")])
            t_analytic, _ = run([os.path.join(BIN, "surfcast-build"), "-q", src, *extra, "-o", analytic])
            captured = os.path.join(tmp, model + "_captured")
            shutil.copytree(analytic, captured)
            t_capture, _ = run([os.path.join(BIN, "surfcast-weights"), "-q", captured, "--views", str(args.views)])
            surfels = json.load(open(os.path.join(analytic, "tileset.json")))["surfels"]
            size = lambda d: os.path.getsize(os.path.join(d, "blocks.bin"))
            times.append((model, surfels, max(t_analytic - t_none, 0.0), t_capture, size(os.path.join(tmp, model + "_none")),
                          size(analytic), size(captured)))
            for view, camera in cameras(analytic).items():
                pixel = render(analytic, "ewa-pixel", camera, os.path.join(tmp, "p.png"))
                for method, tileset in [("analytic", analytic), ("captured", captured)]:
                    surfel = render(tileset, "ewa-surfel", camera, os.path.join(tmp, "s.png"))
                    for region, (mean, p99, n) in errors(pixel, surfel).items():
                        rows.append((model, view, method, region, mean, p99, n))
                print(f"{model} {view} done", file=sys.stderr)

    with open(os.path.join(REPORT, "weights.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["model", "view", "method", "region", "mean_error", "p99_error", "pixels"])
        w.writerows(rows)
    chart(rows)

    print("| model | view | region | analytic mean | analytic P99 | captured mean | captured P99 | pixels |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    keyed = {(m, v, me, r): (mean, p99, n) for m, v, me, r, mean, p99, n in rows}
    for m, v, me, r, mean, p99, n in rows:
        if me != "analytic":
            continue
        c = keyed[(m, v, "captured", r)]
        print(f"| {m} | {v} | {r} | {mean:.3f} | {p99:.3f} | {c[0]:.3f} | {c[1]:.3f} | {n} |")
    print("\n| model | surfels | analytic weights s | capture s | blocks, no weights | analytic | captured (+ edge weights) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for m, n, ta, tc, bn, ba, bc in times:
        print(f"| {m} | {n} | {ta:.2f} | {tc:.2f} | {bn / 1e6:.2f} MB | {ba / 1e6:.2f} MB | {bc / 1e6:.2f} MB |")


def chart(rows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), sharey=True)
    for ax, region in zip(axes, ["interior", "edge"]):
        sel = [r for r in rows if r[3] == region]
        labels = sorted({f"{r[0]} {r[1]}" for r in sel})
        x = np.arange(len(labels))
        for k, method in enumerate(["analytic", "captured"]):
            vals = {f"{r[0]} {r[1]}": r for r in sel if r[2] == method}
            means = [vals[label][4] for label in labels]
            p99 = [vals[label][5] for label in labels]
            ax.bar(x + (k - 0.5) * 0.38, means, 0.38, label=f"{method} mean")
            ax.scatter(x + (k - 0.5) * 0.38, p99, marker="_", s=200, color="k" if k else "r",
                       label=f"{method} P99")
        ax.set_xticks(x, labels, fontsize=8, rotation=40, ha="right")
        ax.set_title(f"per-surfel vs per-pixel brightness error, {region}")
        ax.set_yscale("log")
    axes[0].set_ylabel("|I_surfel / I_pixel - 1|")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(REPORT, "weights.png"), dpi=110)


if __name__ == "__main__":
    main()
