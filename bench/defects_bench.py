#!/usr/bin/env python3
"""Where real scans fail: strays, noise, vegetation, holes and density jumps,
each against an exact reference, and the methods for the radii of sparse
surfels charted speed against accuracy.

Scenes (units are metres): a checkered plane 50 m wide sampled every 0.1 m
(250,000 points, the square 5 m: well resolved, so that the clean plane's
own error is small), with no normals (the builder estimates them, as for
scans), and one defect each:

- outliers 0.5 % / 2 %: points spread uniformly through a slab 5 m thick
  (a tenth of the width) on the plane; mid grey, distinct from both checker
  colours, so that every pixel a stray covers changes;
- outlier clusters: three balls of 36 points (0.15 m standard deviation) 1 m
  above the plane;
- noise 0.25 / 0.5 / 1 step: Gaussian offsets along the normal;
- vegetation: the plane under a canopy of 2,500 leaves (discs of 0.2 m radius
  at random orientations 2 to 4 m up, each sampled by 4 points, as airborne
  LiDAR samples leaves); the reference draws the discs themselves;
- holes: the plane with three occlusion shadows (wedges behind posts seen
  from a scanner) cut out; the reference has the same holes;
- density jumps: the plane sampled at a tenth of the density (0.316 m) or
  a hundredth (1 m) for x > 3 m: sparse but real surfaces, which must stay
  closed;
- a roof ridge: a gabled roof 20 m long, 4 m high, its two sides at 45
  degrees sampled every 0.3 m, on the plane: a crease of a sparse surface.

Each reference is ray-cast from the clean geometry (16 x 16 rays per pixel,
accuracy_bench.py's caster). Every scene is built with each method of
METHODS and drawn with ewa-pixel (unlit); the default build is drawn in every
mode as well. Metrics: FLIP against the reference, and for the strays the
share of the image they change (pixels differing by more than 0.1 from the
clean plane's image, same method and camera). Speed: the build's wall time
and the ewa-pixel GPU ms.

Real scans: every point scan in ../shared/data built with isolation off and
with the default, and measured by surfcast-splat-stats: the distribution of
each leaf splat's radius over its node's median 8th-neighbour distance, and
in surfcast-view's default view (640x480) the share of the image covered by
the largest 1 % of splats. SIDE_BY_SIDE's scans are drawn both ways into
docs/images/isolation-NAME.png (before left, after right).

Writes bench/report/defects.csv, defects.md, defects_speed_accuracy.png,
montage-defects-*.png and real_scans.md; prints the Markdown.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/defects_bench.py [--size 320x240] [--scenes a,b]
       [--real-only | --no-real]
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import accuracy_bench as ab  # noqa: E402

# The shared point scans (PROVENANCE.md), and the two drawn side by side.
SCANS = ["autzen_trim.las", "lone-star.laz", "Megaplot.laz", "lion_takanawa.copc.laz", "CSite1_red1-utm.pcd",
         "fragment.pcd", "milk_cartoon_all_small_clorox.pcd", "table_scene_mug_stereo_textured.pcd"]
SIDE_BY_SIDE = {"Megaplot.laz": "airborne", "lion_takanawa.copc.laz": "terrestrial"}
IMAGES = os.path.join(ab.ROOT, "docs", "images")

# Build options compared: the isolation factor T of surfcast-build (a surfel
# whose 8th neighbour lies beyond T times its level's spacing rho, or beyond
# rho among scattered neighbours, is drawn at rho; 0 is the node's spacing
# rule alone: docs/ARCHITECTURE.md, "Isolated surfels"), and statistical
# outlier removal on top of the default (--remove-outliers, off by default).
METHODS = [("isolation off", ["--isolation", "0"]), ("isolation 2", ["--isolation", "2"]),
           ("isolation 4", ["--isolation", "4"]), ("isolation 6 (default)", []),
           ("isolation 8", ["--isolation", "8"]), ("remove outliers 2", ["--remove-outliers", "2"])]
DEFAULT = "isolation 6 (default)"
MODES = ["points", "circles", "ewa-noprefilter", "ewa-surfel", "ewa-pixel"]
WIDTH, STEP = 50.0, 0.1
CAMERA = "0,-45,40,0,0,0,0,0,1,45"
DARK, LIGHT = np.array([0.1, 0.1, 0.12]), np.array([0.92, 0.9, 0.85])
STRAY = np.array([0.5, 0.5, 0.5])
CHANGED = 0.1  # a pixel counts as changed when a channel moves by more than this


def texture(a, b):
    return ab.checker(a, b, 10.0, DARK, LIGHT)


def plane(extent=(-WIDTH / 2, WIDTH / 2, -WIDTH / 2, WIDTH / 2), spacing=STEP):
    return ab.Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=extent, texture=texture, spacing=spacing)


class HoledPatch(ab.Patch):
    """A patch with regions cut out: holes(a, b) is True where there is no surface."""

    def __init__(self, holes, **kw):
        super().__init__(**kw)
        self.holes = holes

    def inside(self, a, b):
        return super().inside(a, b) & ~self.holes(a, b)


class Discs:
    """Many small discs (centres c, unit normals n, radius r, colours), for the
    vegetation reference: each disc is intersected only with the rays of its
    projected bounding box (see reference())."""

    def __init__(self, c, n, r, colours):
        self.c, self.n, self.r, self.colours = c, n, r, colours


def shadows(a, b):
    """Three occlusion shadows: wedges of 6 degrees behind posts 8 m from a
    scanner at (-20, -20), towards 30, 45 and 60 degrees."""
    da, db = a + 20, b + 20
    angle, dist = np.degrees(np.arctan2(db, da)), np.hypot(da, db)
    out = np.zeros_like(a, dtype=bool)
    for centre in (30, 45, 60):
        out |= (np.abs(angle - centre) < 3) & (dist > 8)
    return out


def sample_plane(rng, patch=None):
    p, _, c = (patch or plane()).samples(rng)
    return p, c


def scene_points(name, rng):
    """(reference surfaces, points, colours) of a scene."""
    if name == "clean":
        p, c = sample_plane(rng)
        return [plane()], p, c
    if name.startswith("outliers"):
        p, c = sample_plane(rng)
        m = int(float(name.split()[1].rstrip("%")) / 100 * len(p))
        q = np.column_stack([rng.uniform(-WIDTH / 2, WIDTH / 2, m), rng.uniform(-WIDTH / 2, WIDTH / 2, m),
                             rng.uniform(0, WIDTH / 10, m)])
        return [plane()], np.vstack([p, q]), np.vstack([c, np.repeat(STRAY[None], m, axis=0)])
    if name == "outlier clusters":
        p, c = sample_plane(rng)
        q = np.vstack([centre + rng.normal(0, 0.15, (36, 3)) for centre in ([-8, 4, 1], [3, -6, 1], [10, 10, 1])])
        return [plane()], np.vstack([p, q]), np.vstack([c, np.repeat(STRAY[None], len(q), axis=0)])
    if name.startswith("noise"):
        p, c = sample_plane(rng)
        sigma = float(name.split()[1]) * STEP
        p[:, 2] += rng.normal(0, sigma, len(p))
        return [plane()], p, c
    if name == "vegetation":
        p, c = sample_plane(rng)
        k = 2500
        centres = np.column_stack([rng.uniform(-20, 5, k), rng.uniform(-15, 10, k), rng.uniform(2, 4, k)])
        normals = rng.normal(size=(k, 3))
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        colours = np.column_stack([rng.uniform(0.1, 0.35, k), rng.uniform(0.35, 0.6, k), rng.uniform(0.05, 0.15, k)])
        radius = 0.2
        # Four points per leaf, uniform over its disc.
        u = np.cross(normals, np.where(np.abs(normals[:, :1]) < 0.9, [[1, 0, 0]], [[0, 1, 0]]))
        u /= np.linalg.norm(u, axis=1)[:, None]
        v = np.cross(normals, u)
        leaf = np.repeat(np.arange(k), 4)
        rad = radius * np.sqrt(rng.uniform(0, 1, len(leaf)))
        ang = rng.uniform(0, 2 * np.pi, len(leaf))
        q = centres[leaf] + (rad * np.cos(ang))[:, None] * u[leaf] + (rad * np.sin(ang))[:, None] * v[leaf]
        return [plane(), Discs(centres, normals, radius, colours)], np.vstack([p, q]), np.vstack([c, colours[leaf]])
    if name == "holes":
        patch = HoledPatch(shadows, c=[0, 0, 0], u=[1, 0, 0], v=[0, 1, 0],
                           extent=(-WIDTH / 2, WIDTH / 2, -WIDTH / 2, WIDTH / 2), texture=texture, spacing=STEP)
        p, c = sample_plane(rng, patch)
        return [patch], p, c
    if name == "roof ridge":
        p, c = sample_plane(rng)
        roof_tex = lambda a, b: ab.checker(a, b, 4.0, np.array([0.55, 0.15, 0.1]), np.array([0.85, 0.5, 0.35]))
        half = 2 * np.sqrt(2)
        sides = [ab.Patch([0, side * 2, 2], [1, 0, 0], [0, -side * np.sqrt(0.5), np.sqrt(0.5)],
                          extent=(-10, 10, -half, half), texture=roof_tex, spacing=0.3) for side in (-1, 1)]
        roof = [sample_plane(rng, side) for side in sides]
        return [plane(), *sides], np.vstack([p] + [q for q, _ in roof]), np.vstack([c] + [k for _, k in roof])
    if name.startswith("density jump"):
        jump, ratio = 3.0, float(name.split()[2].rstrip("x"))
        dense = plane(extent=(-WIDTH / 2, jump, -WIDTH / 2, WIDTH / 2))
        sparse = plane(extent=(jump, WIDTH / 2, -WIDTH / 2, WIDTH / 2), spacing=STEP * np.sqrt(ratio))
        (p1, c1), (p2, c2) = sample_plane(rng, dense), sample_plane(rng, sparse)
        return [plane()], np.vstack([p1, p2]), np.vstack([c1, c2])
    raise ValueError(name)


SCENES = ["outliers 0.5%", "outliers 2%", "outlier clusters", "noise 0.25", "noise 0.5", "noise 1", "vegetation",
          "holes", "density jump 10x", "density jump 100x", "roof ridge"]


def reference(surfaces, camera, width, height):
    """accuracy_bench.reference for planes, plus Discs by projected boxes."""
    planes = [s for s in surfaces if not isinstance(s, Discs)]
    discs = [s for s in surfaces if isinstance(s, Discs)]
    if not discs:
        return ab.reference(planes, camera, width, height)
    eye, f, r, u, eta = ab.camera_rays(camera, width, height)
    d = discs[0]
    rel = d.c - eye
    z = rel @ f
    px = width / 2 + eta * (rel @ r) / z
    py = height / 2 - eta * (rel @ u) / z
    reach = eta * d.r / np.maximum(z - d.r, 1e-6) + 1
    x0, x1 = np.floor(px - reach).astype(int), np.ceil(px + reach).astype(int)
    y0, y1 = np.floor(py - reach).astype(int), np.ceil(py + reach).astype(int)
    ss = ab.SUPERSAMPLE ** 2

    def leaves(y, dirs, best, colour):
        for i in np.nonzero((y0 <= y) & (y <= y1) & (z > 0))[0]:
            a, b = max(x0[i], 0) * ss, min(x1[i] + 1, width) * ss
            if a >= b:
                continue
            dd = dirs[a:b]
            denom = dd @ d.n[i]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((d.c[i] - eye) @ d.n[i]) / denom
            hitp = eye + t[:, None] * dd
            inside = (t > 0) & np.isfinite(t) & (np.sum((hitp - d.c[i]) ** 2, axis=1) <= d.r ** 2) & (t < best[a:b])
            best[a:b][inside] = t[inside]
            colour[a:b][inside] = d.colours[i]

    return ab.reference(planes, camera, width, height, more=leaves)


def build(ply, tileset, options, weights=True):
    """surfcast-build (with analytic weights, which ewa-surfel reads, unless
    not `weights`); returns its wall seconds and neighbour step's thread-seconds."""
    shutil.rmtree(tileset, ignore_errors=True)
    start = time.perf_counter()
    extra = ["--weights", "analytic"] if weights else []
    out = subprocess.run([os.path.join(ab.BIN, "surfcast-build"), ply, "-o", tileset, *extra, *options],
                         check=True, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    steps = re.search(r"neighbours\+h\+weights ([0-9.]+)", out.stdout + out.stderr)
    return seconds, float(steps.group(1)) if steps else float("nan")


def real_scans(tmp):
    """Per scan: splat statistics with isolation off and on, and the side-by-side images."""
    import json
    from PIL import Image
    os.makedirs(IMAGES, exist_ok=True)
    lines = ["Real scans, every leaf, surfcast-view's default view at 640x480: r / m is a leaf splat's radius over "
             "its node's median 8th-neighbour distance (percentiles); top 1 % is the share of the image covered "
             "by the largest 1 % of splats (circles of their projected radius, occlusion ignored); r / M is the radius over "
             "the median 8th-neighbour distance of every leaf, where strays in nodes of their own show. Covered: pixels "
             "the default view covers (holes would lower it); bytes: blocks.bin.", "",
             "| scan | splats | r / m p50 after | p99 before | p99 after | p99.9 before | p99.9 after | max before | max after | "
             "r / M max before | after | top 1 % before | top 1 % after | covered before | after | bytes before | after |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for scan in SCANS:
        src = os.path.join(ab.DATA, scan)
        stats, pngs = {}, {}
        for label, options in (("before", ["--isolation", "0"]), ("after", [])):
            tileset = os.path.join(tmp, "scan-" + label)
            build(src, tileset, options, weights=False)
            stats[label] = json.loads(ab.run([os.path.join(ab.BIN, "surfcast-splat-stats"), tileset, "--size", "640x480"]))
            stats[label]["bytes"] = os.path.getsize(os.path.join(tileset, "blocks.bin"))
            pngs[label] = os.path.join(tmp, label + ".png")
            view = ab.run([os.path.join(ab.BIN, "surfcast-view"), "--headless", tileset, "--size", "640x480", "--out",
                           pngs[label]])
            stats[label]["covered"] = json.loads(view.strip().splitlines()[-1])["pixels_covered"]
        b, a = stats["before"], stats["after"]
        lines.append(f"| {scan} | {a['splats']} | {a['ratio_p50']:.2f} | {b['ratio_p99']:.2f} | {a['ratio_p99']:.2f} | "
                     f"{b['ratio_p999']:.2f} | {a['ratio_p999']:.2f} | {b['ratio_max']:.1f} | {a['ratio_max']:.1f} | "
                     f"{b['set_ratio_max']:.1f} | {a['set_ratio_max']:.1f} | "
                     f"{100 * b['largest_1pc_image_share']:.1f} % | {100 * a['largest_1pc_image_share']:.1f} % | "
                     f"{b['covered']} | {a['covered']} | {b['bytes']} | {a['bytes']} |")
        print(lines[-1], file=sys.stderr)
        if scan in SIDE_BY_SIDE:
            left, right = Image.open(pngs["before"]), Image.open(pngs["after"])
            sheet = Image.new("RGB", (left.width + right.width, left.height), "white")
            sheet.paste(left, (0, 0))
            sheet.paste(right, (left.width, 0))
            name = os.path.splitext(os.path.splitext(scan)[0])[0]
            sheet.save(os.path.join(IMAGES, f"isolation-{name}.png"))
    ab.write_markdown("real_scans.md", lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scenes", default="", help="comma-separated subset of: " + ", ".join(SCENES))
    ap.add_argument("--real-only", action="store_true", help="only the real scans")
    ap.add_argument("--no-real", action="store_true", help="no real scans")
    args = ap.parse_args()
    if args.real_only:
        with tempfile.TemporaryDirectory() as tmp:
            real_scans(tmp)
        return
    width, height = (int(v) for v in args.size.split("x"))
    wanted = args.scenes.split(",") if args.scenes else SCENES
    os.makedirs(ab.REPORT, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        # The clean plane, once per method: the image the strays change.
        surfaces, p, c = scene_points("clean", np.random.default_rng(1))
        clean_ref = ab.reference(surfaces, CAMERA, width, height)
        ply = os.path.join(tmp, "clean.ply")
        ab.write_ply(ply, p, np.zeros_like(p), c)
        clean = {}  # (method, mode): the clean plane's image
        for label, options in METHODS:
            build(ply, os.path.join(tmp, "clean"), options)
            for mode in MODES if label == DEFAULT else ["ewa-pixel"]:
                clean[label, mode], _, _ = ab.render(os.path.join(tmp, "clean"), mode, CAMERA, args.size, 1,
                                                     os.path.join(tmp, "f.png"))
        clean_flip = ab.metrics(clean_ref, clean[DEFAULT, "ewa-pixel"])[2]
        for name in wanted:
            surfaces, p, c = scene_points(name, np.random.default_rng(1))
            ref = clean_ref if surfaces[0].__class__ is ab.Patch and len(surfaces) == 1 else reference(
                surfaces, CAMERA, width, height)
            ply = os.path.join(tmp, "scene.ply")
            ab.write_ply(ply, p, np.zeros_like(p), c)
            images = []
            for label, options in METHODS:
                tileset = os.path.join(tmp, "scene")
                seconds, neighbour_s = build(ply, tileset, options)
                modes = MODES if label == DEFAULT else ["ewa-pixel"]
                for mode in modes:
                    img, ms, _ = ab.render(tileset, mode, CAMERA, args.size, args.repeat, os.path.join(tmp, "f.png"))
                    changed = float((np.max(np.abs(img - clean[label, mode]), axis=2) > CHANGED).mean())
                    rows.append({"scene": name, "method": label, "mode": mode, "flip": ab.metrics(ref, img)[2],
                                 "changed": changed, "build_s": seconds, "neighbour_s": neighbour_s, "ms": ms})
                    if mode == "ewa-pixel":
                        images.append((label, img))
                    print(f"{name} | {label} | {mode}: FLIP {rows[-1]['flip']:.4f}, changed {changed:.3f}, "
                          f"build {seconds:.2f} s, {ms:.1f} ms", file=sys.stderr)
            ab.montage("defects-" + name.replace(" ", "-").replace("%", "pc"), ref, images)
        if not args.no_real:
            real_scans(tmp)
    ab.write_csv("defects.csv", rows)
    chart(rows)
    write_report(rows, args.size, clean_flip)


def chart(rows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    labels = [m for m, _ in METHODS]
    scenes = [s for s in SCENES if any(r["scene"] == s for r in rows)]
    for k, scene in enumerate(scenes):
        sel = {r["method"]: r for r in rows if r["scene"] == scene and r["mode"] == "ewa-pixel"}
        axes[0].plot(range(len(labels)), [sel[m]["flip"] for m in labels], marker="o", color=f"C{k}", label=scene)
    axes[0].set_xticks(range(len(labels)), labels, rotation=20, fontsize=8)
    axes[0].set_ylabel("FLIP against the exact reference (ewa-pixel)")
    axes[0].set_yscale("log")
    axes[0].set_title("Per scene and method")
    axes[0].legend(fontsize=7)
    for k, label in enumerate(labels):
        sel = [r for r in rows if r["method"] == label and r["mode"] == "ewa-pixel" and r["scene"] in scenes]
        axes[1].scatter([np.sum([r["neighbour_s"] for r in sel])], [np.mean([r["flip"] for r in sel])], s=80,
                        color=f"C{k}", label=label)
    axes[1].set_xlabel("thread-seconds in neighbours + h + weights, all scenes")
    axes[1].set_ylabel("mean FLIP over the scenes (ewa-pixel)")
    axes[1].set_title("Speed against accuracy")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(ab.REPORT, "defects_speed_accuracy.png"), dpi=110)


def write_report(rows, size, clean_flip):
    labels = [m for m, _ in METHODS]
    scenes = [s for s in SCENES if any(r["scene"] == s for r in rows)]
    lines = [f"Defect scenes at {size} (ewa-pixel, unlit), FLIP against each scene's exact reference (the clean "
             "plane, or the scene's own surfaces); for strays, the share of the image they change (in parentheses):", "",
             "| scene | " + " | ".join(labels) + " |", "|---|" + "---:|" * len(labels)]
    for scene in scenes:
        sel = {r["method"]: r for r in rows if r["scene"] == scene and r["mode"] == "ewa-pixel"}
        cells = [f"{sel[m]['flip']:.4f}" + (f" ({100 * sel[m]['changed']:.1f} %)" if scene.startswith("outlier") else "")
                 for m in labels]
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    lines.append("| mean | " + " | ".join(f"{np.mean([r['flip'] for r in rows if r['method'] == m and r['mode'] == 'ewa-pixel' and r['scene'] in scenes]):.4f}"
                                          for m in labels) + " |")
    lines.append("| build s, all scenes | " + " | ".join(
        f"{np.sum([r['build_s'] for r in rows if r['method'] == m and r['mode'] == 'ewa-pixel' and r['scene'] in scenes]):.1f}"
        for m in labels) + " |")
    lines.append("| neighbours + h + weights, thread-s | " + " | ".join(
        f"{np.sum([r['neighbour_s'] for r in rows if r['method'] == m and r['mode'] == 'ewa-pixel' and r['scene'] in scenes]):.2f}"
        for m in labels) + " |")
    lines += ["", f"The clean plane itself (default build): FLIP {clean_flip:.4f}."]
    lines += ["", f"Every mode on the default build ({DEFAULT}), FLIP (GPU ms):", "",
              "| scene | " + " | ".join(MODES) + " |", "|---|" + "---:|" * len(MODES)]
    for scene in scenes:
        sel = {r["mode"]: r for r in rows if r["scene"] == scene and r["method"] == DEFAULT}
        best = min(MODES, key=lambda m: sel[m]["flip"])
        lines.append(f"| {scene} | " + " | ".join(
            (f"**{sel[m]['flip']:.4f}**" if m == best else f"{sel[m]['flip']:.4f}") + f" ({sel[m]['ms']:.0f})"
            for m in MODES) + " |")
    ab.write_markdown("defects.md", lines)


if __name__ == "__main__":
    main()
