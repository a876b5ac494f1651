#!/usr/bin/env python3
"""Renderer throughput benchmark: object-space EWA on Vulkan.

Builds the built-in scanned scene at two sizes (its leaves are the input
points, so --scene-points sets the splat count), then renders every leaf with
each mode of surfcast-view --headless at 1280x720 from the default framing
camera, and reports the median GPU time (timestamps, --repeat N) and splats/s,
against 1-px points of the same surfels in the same run. EWA modes are run with
both expansions (instanced quads, geometry shader). Prints Markdown.

Usage: python3 bench/render_bench.py [--sizes 100000,1000000] [--repeat 5] [--device D]
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")
MODES = ["points", "circles", "ewa-noprefilter", "ewa-surfel", "ewa-pixel"]


def render(tileset, mode, expansion, repeat, device, out_png):
    cmd = [os.path.join(BIN, "surfcast-view"), "--headless", tileset, "--size", "1280x720", "--mode", mode,
           "--repeat", str(repeat), "--out", out_png]
    if mode != "cpu-reference":
        cmd += ["--expansion", expansion]
    if device:
        cmd += ["--device", device]
    line = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1]
    return json.loads(line)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="100000,1000000")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--device", default="")
    args = ap.parse_args()
    rows = []
    device = "?"
    with tempfile.TemporaryDirectory() as tmp:
        for size in [int(s) for s in args.sizes.split(",")]:
            tileset = os.path.join(tmp, f"scene{size}")
            subprocess.run([os.path.join(BIN, "surfcast-build"), "-q", "--weights", "analytic", "--default-scene", "--scene-points", str(size),
                            "-o", tileset], check=True, capture_output=True)
            base = None
            configs = [(m, "quad") for m in MODES] + [(m, "geometry") for m in MODES if m.startswith("ewa")]
            for mode, expansion in configs:
                r = render(tileset, mode, expansion, args.repeat, args.device, os.path.join(tmp, "f.png"))
                device = r.get("device", device)
                ms = r["gpu_ms"]["total"]
                rate = r["splats"] / (ms / 1000)
                if mode == "points":
                    base = rate
                rows.append((r["splats"], mode, expansion, ms, r["gpu_ms"]["visibility"], r["gpu_ms"]["accumulate"],
                             r["gpu_ms"]["resolve"], rate, rate / base, r["pixels_covered"]))
                print(f"{r['splats']} {mode} {expansion}: {ms:.1f} ms", file=sys.stderr)
            r = render(tileset, "cpu-reference", "", 1, args.device, os.path.join(tmp, "f.png"))
            rows.append((r["splats"], "cpu-reference", "-", r["cpu_ms"], 0, 0, 0, r["splats"] / (r["cpu_ms"] / 1000),
                         r["splats"] / (r["cpu_ms"] / 1000) / base, r["pixels_covered"]))
    print(f"Device: {device}; host: {platform.node()}, {os.cpu_count()} cores; 1280x720, median of {args.repeat}.\n")
    print("| splats | mode | expansion | GPU ms | visibility | accumulate | resolve | M splats/s | vs points | pixels covered |")
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for n, mode, exp, ms, vis, acc, res, rate, rel, cov in rows:
        print(f"| {n} | {mode} | {exp} | {ms:.1f} | {vis:.1f} | {acc:.1f} | {res:.1f} | {rate / 1e6:.2f} | {rel:.2f} | {cov} |")


if __name__ == "__main__":
    main()
