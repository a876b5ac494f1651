#!/usr/bin/env python3
"""Transparency (Zwicker et al. 2001, §6): translucent scenes against exact
alpha-composited ray-cast references, for each number of fragment layers l,
on the GPU (depth peeling) and in the CPU reference (the paper's A-buffer).

Scenes (surfels on the accuracy harness's jittered grid, 0.5 units apart,
opacity stored per surfel from the PLY's alpha):
- translucent-crossing: two planes crossing at 30 degrees, opacity 0.5 each;
- translucent-sphere: a sphere of opacity 0.5 (both of its sides show) over
  an opaque checkerboard;
- stacked-layers: three parallel planes 4 units apart, opacity 0.5 each, over
  the white background: more surfaces than l = 1 or 2 keep.

The references cast 16 x 16 rays per pixel, composite every surface a ray
meets back to front (eq. 12) and average. FLIP over the whole image and over
the silhouette pixels alone: those whose rays do not all meet the same
surfaces. Frames are drawn with --backface-cull off (a translucent sphere
shows its far side) and the defaults otherwise (edge antialiasing on).

With --baseline BIN (the bin folder of another build, e.g. the commit before
transparency), the opaque frame time is measured side by side: the built-in
scanned scene (1.5 M surfels, opaque) at 1280 x 720 drawn by both builds,
alternating, 8 rounds of --repeat frames each; the translucent scenes' own
frames (10-20 ms) are too short to tell 5 % from the machine's noise.

Writes bench/report/transparency.csv, transparency.md and transparency.png.

Usage: bench/.venv/bin/python bench/transparency_bench.py [--size 320x240] [--baseline DIR]
"""
import argparse
import os
import sys
import tempfile

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import accuracy_bench as ab  # noqa: E402
import edge_aa_bench as eb  # noqa: E402

LAYERS = [1, 2, 3, 4, 6, 8]


class TranslucentSphere(ab.Sphere):
    """A sphere whose far side shows through: intersect_all gives both hits."""

    def intersect_all(self, o, d):
        oc = o - self.c
        b = np.einsum("ij,ij->i", d, oc)
        disc = b * b - (np.einsum("ij,ij->i", oc, oc) - self.r ** 2)
        root = np.sqrt(np.maximum(disc, 0))
        hits = []
        for t in (-b - root, -b + root):
            t = np.where((disc >= 0) & (t > 0), t, np.inf)
            p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
            hits.append((t, self.angles(p)))
        return hits


def scenes():
    red, green, blue = np.array([0.85, 0.2, 0.15]), np.array([0.2, 0.75, 0.25]), np.array([0.15, 0.3, 0.85])
    dark, light = np.array([0.1, 0.1, 0.12]), np.array([0.92, 0.9, 0.85])
    solid = lambda c: (lambda a, b: np.repeat(c[None, :], len(a), axis=0))
    s, c30 = 0.5, np.sqrt(3) / 2
    return {
        "translucent-crossing": ([(ab.Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-20, 20, -20, 20), texture=solid(red)), 0.5),
                                  (ab.Patch([0, 0, 0], [1, 0, 0], [0, c30, s], extent=(-20, 20, -20, 20), texture=solid(blue)), 0.5)],
                                 "8,-45,30,0,0,0,0,0,1,45"),
        "translucent-sphere": ([(TranslucentSphere([0, 0, 10], 9, lambda phi, theta: np.repeat(blue[None, :], len(phi), axis=0)), 0.5),
                                (ab.Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-25, 25, -25, 25),
                                          texture=lambda a, b: ab.checker(a, b, 4.0, dark, light)), 1.0)],
                               "0,-40,30,0,0,6,0,0,1,45"),
        "stacked-layers": ([(ab.Patch([0, 0, z], [1, 0, 0], [0, 1, 0], extent=(-15 + k, 15 - k, -15 + k, 15 - k), texture=solid(c)), 0.5)
                            for k, (z, c) in enumerate([(8, red), (4, green), (0, blue)])],
                           "0,-45,40,0,0,2,0,0,1,40"),
    }


def reference(surfaces, camera, width, height):
    """Every hit of every ray composited back to front; and the silhouette
    pixels, whose rays meet different sets of surfaces."""
    image = np.zeros((height, width, 3))
    edge = np.zeros((height, width), bool)
    samples = ab.SUPERSAMPLE ** 2
    for y, o, d in ab.row_rays(camera, width, height):
        ts, colours, alphas = [], [], []
        mask = np.zeros(len(d), np.int64)
        for k, (surface, opacity) in enumerate(surfaces):
            hits = surface.intersect_all(o, d) if hasattr(surface, "intersect_all") else [surface.intersect(o, d)]
            for j, (t, param) in enumerate(hits):
                hit = np.isfinite(t)
                c = np.zeros((len(d), 3))
                if hit.any():
                    c[hit] = surface.colour(tuple(p[hit] for p in param))
                ts.append(t)
                colours.append(c)
                alphas.append(np.where(hit, opacity, 0.0))
                mask |= hit.astype(np.int64) << (2 * k + j)
        t = np.array(ts)
        order = np.argsort(t, axis=0)[::-1]  # far to near
        colour = np.repeat(ab.BACKGROUND[None, :], len(d), axis=0)
        cols, alps = np.array(colours), np.array(alphas)
        rows = np.arange(len(d))
        for layer in order:
            a = alps[layer, rows][:, None]
            colour = cols[layer, rows] * a + colour * (1 - a)  # eq. 12
        image[y] = colour.reshape(width, samples, 3).mean(axis=1)
        m = mask.reshape(width, samples)
        edge[y] = m.min(axis=1) != m.max(axis=1)
    return image, edge


def write_ply(path, points, normals, colours, alphas):
    n = len(points)
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\n"
              "property double x\nproperty double y\nproperty double z\n"
              "property float nx\nproperty float ny\nproperty float nz\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\nend_header\n" % n)
    rec = np.zeros(n, dtype=[("p", "<f8", 3), ("n", "<f4", 3), ("c", "u1", 3), ("a", "u1")])
    rec["p"], rec["n"] = points, normals
    rec["c"] = np.clip(np.round(colours * 255), 0, 255)
    rec["a"] = np.clip(np.round(alphas * 255), 0, 255)
    with open(path, "wb") as fh:
        fh.write(header.encode())
        fh.write(rec.tobytes())


def build(name, surfaces, tmp, rng):
    parts = [(s.samples(rng), a) for s, a in surfaces]
    pts = np.concatenate([p for (p, _, _), _ in parts])
    nrm = np.concatenate([n for (_, n, _), _ in parts])
    col = np.concatenate([c for (_, _, c), _ in parts])
    alp = np.concatenate([np.full(len(p), a) for (p, _, _), a in parts])
    ply = os.path.join(tmp, name + ".ply")
    write_ply(ply, pts, nrm, col, alp)
    tileset = os.path.join(tmp, name)
    ab.run([os.path.join(ab.BIN, "surfcast-build"), "-q", ply, "-o", tileset])
    return tileset


def opaque_timing(tmp, repeat, baseline):
    """Opaque frames of this build against the baseline's, alternating: per
    round, the ratio of the two medians of `repeat` frames."""
    tileset = os.path.join(tmp, "scene")
    ab.run([os.path.join(ab.BIN, "surfcast-build"), "-q", "--default-scene", "-o", tileset])
    own, rows = ab.BIN, []
    for _ in range(8):
        ms = {}
        for label, bin_dir in (("this", own), ("baseline", baseline)):
            ab.BIN = bin_dir
            try:
                ms[label] = ab.render(tileset, "ewa-pixel", None, "1280x720", repeat, os.path.join(tmp, "t.png"))[1]
            finally:
                ab.BIN = own
        rows.append({"this_ms": ms["this"], "baseline_ms": ms["baseline"], "ratio": ms["this"] / ms["baseline"]})
        print(f"opaque: {ms['this']:.1f} ms against {ms['baseline']:.1f} ms", file=sys.stderr)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--baseline", help="bin folder of another build: opaque frame time side by side")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    os.makedirs(ab.REPORT, exist_ok=True)
    rng = np.random.default_rng(1)
    rows, tiles = [], []
    with tempfile.TemporaryDirectory() as tmp:
        png = os.path.join(tmp, "frame.png")
        for name, (surfaces, camera) in scenes().items():
            ref, edge = reference(surfaces, camera, width, height)
            tileset = build(name, surfaces, tmp, rng)
            tiles.append((name + " reference", ref))
            for mode in ("ewa-pixel", "cpu-reference"):
                for layers in LAYERS:
                    img, ms, splats = ab.render(tileset, mode, camera, args.size, 1 if mode == "cpu-reference" else args.repeat,
                                                png, options=["--backface-cull", "off", "--layers", str(layers)])
                    sc = eb.scores(ref, img, edge)
                    rows.append({"scene": name, "mode": mode, "layers": layers, "splats": splats, "ms": ms, **sc})
                    print(f"{name} {mode} l={layers}: {ms:.1f} ms, FLIP {sc['flip']:.4f}, silhouettes {sc['flip_edge']:.4f}",
                          file=sys.stderr)
                    if mode == "ewa-pixel" and layers in (1, 3):
                        tiles.append((f"{name} l={layers}", img))
        timing = opaque_timing(tmp, args.repeat, args.baseline) if args.baseline else []
    ab.write_csv("transparency.csv", rows)
    sheet = Image.new("RGB", (width * 3, height * len(scenes())), "white")
    for i, (_, img) in enumerate(tiles):
        sheet.paste(Image.fromarray(np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)), ((i % 3) * width, (i // 3) * height))
    sheet.save(os.path.join(ab.REPORT, "transparency.png"))
    lines = [f"Translucent scenes at {args.size} against 16 x 16 ray-cast references composited by eq. 12; "
             f"GPU time = median of {args.repeat}, CPU one run. Montage (transparency.png): reference, l = 1, l = 3 per scene.", "",
             "| scene | mode | l | ms | FLIP | FLIP silhouettes | PSNR dB |", "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['mode']} | {r['layers']} | {r['ms']:.1f} | {r['flip']:.4f} | {r['flip_edge']:.4f} | "
                     f"{r['psnr']:.2f} |")
    if timing:
        ratios = [t["ratio"] for t in timing]
        lines += ["", "Opaque frames (the built-in scene, ewa-pixel, 1280 x 720), this build against the baseline, "
                  "alternating rounds:", "", "| round | this ms | baseline ms | ratio |", "|---:|---:|---:|---:|"]
        for i, t in enumerate(timing):
            lines.append(f"| {i + 1} | {t['this_ms']:.1f} | {t['baseline_ms']:.1f} | {t['ratio']:.3f} |")
        lines.append(f"| geometric mean | | | {float(np.exp(np.mean(np.log(ratios)))):.3f} |")
    ab.write_markdown("transparency.md", lines)


if __name__ == "__main__":
    main()
