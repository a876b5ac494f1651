#!/usr/bin/env python3
"""Speed against accuracy: every renderer mode against exact references.

Meshes: the shared bunny, horse and igea, their vertices built as surfels
(--vertices-only), drawn grey (--color 0.8) with Lambert shading, against the
triangle mesh rasterized with 4 x 4 samples per pixel and the renderer's own
Lambert headlight on the same grey (surfcast-mesh-reference).

Synthetic scenes with exact ground truth: a CPU ray caster (numpy) renders
each scene's analytic surfaces with 16 x 16 stratified samples per pixel and
band-limited textures (square waves cut after the 7th harmonic), so the
reference is the true pixel-area average. The same surfaces are sampled into
surfels (a jittered grid at 0.5 units, colour = the texture at the sample,
exact normals), written as PLY, built with surfcast-build and rendered by
surfcast-view --headless in every mode (1-px points, circles, EWA without
prefilter, EWA per-surfel, EWA per-pixel, the CPU reference), unlit on white.

Metrics against the reference: PSNR and SSIM (scikit-image) and mean FLIP
(NVIDIA's flip-evaluator, LDR). Time: the median GPU ms of --repeat N (CPU ms
for cpu-reference). Writes bench/report/accuracy.csv, accuracy_speed.png
(FLIP against frame time, one point per scene and mode), a montage per scene
(reference and every mode) and accuracy.md; prints the Markdown.

Model sweep on the meshes: --no-radius (irregular vertex sampling) and the
normal bits under Lambert and Phong shading, bytes against PSNR and FLIP
(mesh_model.csv, mesh_model.md; alone with --mesh-model-only).

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/accuracy_bench.py [--size 320x240] [--repeat 3]
"""
import argparse
import csv
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile

import flip_evaluator as flip
import numpy as np
from PIL import Image
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("SURFCAST_DATA_DIR", os.path.join(ROOT, "..", "shared", "data"))
# The shared scanned meshes: their vertices as surfels against the mesh itself
# (surfcast-mesh-reference: 4 x 4 samples per pixel, the renderer's Lambert).
MESHES = ["bunny", "horse", "igea"]
BIN = os.path.join(ROOT, "build", "bin")
REPORT = os.path.join(ROOT, "bench", "report")
MODES = ["points", "circles", "ewa-noprefilter", "ewa-surfel", "ewa-pixel", "cpu-reference"]
# The reconstruction kernel sweep (ewa-pixel): V^r = (k h)^2 I.
KERNEL_SCALES = [0.4, 0.5, 0.6, 0.7, 0.85, 1.0]
# The low-pass filter sweep (ewa-pixel): V^h = v I, pixels^2. A box-filtered
# (supersampled) reference pixel corresponds to a variance of about 1/12.
LOWPASS = [0.0, 0.1, 0.25, 0.5, 1.0]
# The model sweep: surfcast-build options against bytes and error, one at a
# time from the defaults (--position-fraction 8, --normal-bits 10, radii on).
QUANTIZATION = ([("position-fraction", f) for f in (1, 2, 4, 8, 16)] + [("normal-bits", n) for n in (6, 8, 10, 12)] +
                [("no-radius", None)])
# Scenes with analytic geometry for the geometric error (surfcast-geom-error).
GEOMETRY = {"textured-sphere": ["sphere", "0", "0", "0", "10"]}
SPACING = 0.5      # surfel sampling step (world units)
SUPERSAMPLE = 16   # per axis: 256 rays per pixel
BACKGROUND = np.array([1.0, 1.0, 1.0])


# --- band-limited textures -------------------------------------------------

def square_wave(t, harmonics=7):
    """(4/pi) sum_{odd k <= harmonics} sin(k t)/k: a square wave without its
    frequencies above the 7th harmonic."""
    s = np.zeros_like(t)
    for k in range(1, harmonics + 1, 2):
        s += np.sin(k * t) / k
    return np.clip(4 / np.pi * s, -1, 1)


def checker(a, b, period, dark, light):
    v = 0.5 + 0.5 * square_wave(np.pi * a / (period / 2)) * square_wave(np.pi * b / (period / 2))
    return dark[None, :] * (1 - v[:, None]) + light[None, :] * v[:, None]


# --- surfaces: intersection, texture, sampling -------------------------------

class Patch:
    """A planar patch: centre c, unit axes u, v; (a, b) in [a0, a1] x [b0, b1],
    or a disc of the given radius."""

    def __init__(self, c, u, v, extent=None, radius=None, texture=None, normal_sign=1, spacing=SPACING):
        self.spacing = spacing
        self.c, self.u, self.v = np.array(c, float), np.array(u, float), np.array(v, float)
        self.u /= np.linalg.norm(self.u)
        self.v /= np.linalg.norm(self.v)
        self.n = normal_sign * np.cross(self.u, self.v)
        self.extent, self.radius, self.texture = extent, radius, texture

    def inside(self, a, b):
        if self.radius is not None:
            return a * a + b * b <= self.radius ** 2
        a0, a1, b0, b1 = self.extent
        return (a >= a0) & (a <= a1) & (b >= b0) & (b <= b1)

    def intersect(self, o, d):
        denom = d @ self.n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.c - o) @ self.n) / denom
        p = o + t[:, None] * d
        a, b = (p - self.c) @ self.u, (p - self.c) @ self.v
        ok = (t > 0) & np.isfinite(t) & self.inside(a, b)
        return np.where(ok, t, np.inf), (a, b)

    def colour(self, ab):
        return self.texture(*ab)

    def samples(self, rng):
        if self.radius is not None:
            a0 = b0 = -self.radius
            a1 = b1 = self.radius
        else:
            a0, a1, b0, b1 = self.extent
        h = self.spacing
        a, b = np.meshgrid(np.arange(a0 + h / 2, a1, h), np.arange(b0 + h / 2, b1, h))
        a = a.ravel() + rng.uniform(-0.3, 0.3, a.size) * h
        b = b.ravel() + rng.uniform(-0.3, 0.3, b.size) * h
        keep = self.inside(a, b)
        a, b = a[keep], b[keep]
        p = self.c + a[:, None] * self.u + b[:, None] * self.v
        return p, np.repeat(self.n[None, :], len(a), axis=0), self.colour((a, b))


class Sphere:
    def __init__(self, c, r, texture, spacing=SPACING):
        self.c, self.r, self.texture, self.spacing = np.array(c, float), r, texture, spacing

    def angles(self, p):
        q = (p - self.c) / self.r
        return np.arctan2(q[:, 1], q[:, 0]), np.arccos(np.clip(q[:, 2], -1, 1))

    def intersect(self, o, d):
        oc = o - self.c
        b = np.einsum("ij,ij->i", d, oc)
        disc = b * b - (np.einsum("ij,ij->i", oc, oc) - self.r ** 2)
        t = -b - np.sqrt(np.maximum(disc, 0))
        t = np.where((disc >= 0) & (t > 0), t, np.inf)
        p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
        return t, self.angles(p)

    def colour(self, angles):
        return self.texture(*angles)

    def samples(self, rng):
        n = int(4 * np.pi * self.r ** 2 / self.spacing ** 2)
        i = np.arange(n) + 0.5
        z = 1 - 2 * i / n
        phi = np.pi * (3 - np.sqrt(5)) * i
        q = np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
        p = self.c + self.r * q
        return p, q, self.colour(self.angles(p))


def scenes():
    dark, light = np.array([0.1, 0.1, 0.12]), np.array([0.92, 0.9, 0.85])
    red, blue, orange = np.array([0.85, 0.2, 0.15]), np.array([0.15, 0.3, 0.85]), np.array([0.95, 0.6, 0.1])
    solid = lambda c: (lambda a, b: np.repeat(c[None, :], len(a), axis=0))
    tex_checker = lambda a, b: checker(a, b, 4.0, dark, light)
    zone = lambda a, b: (0.5 + 0.5 * np.cos(0.052 * (a * a + b * b)))[:, None] * (light - dark) + dark
    sphere_checker = lambda phi, theta: checker(phi * 12 / np.pi, theta * 6 / np.pi, 2.0, dark, light)
    z_t = 0.5 * 1.5 * SPACING  # 0.5 h, with h about 1.5 x the sampling step
    s = 0.5  # sin(30 deg)
    c30 = np.sqrt(3) / 2
    return {
        "checker-horizon": ([Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-60, 60, -5, 300), texture=tex_checker)],
                            "0,-12,8,0,40,0,0,0,1,50"),
        "zone-plate": ([Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-30, 30, -30, 30), texture=zone)],
                       "0,-30,55,0,0,0,0,0,1,50"),
        # Denser than the rest (0.15): several levels, for the model sweep.
        "textured-sphere": ([Sphere([0, 0, 0], 10, sphere_checker, spacing=0.15)], "0,-35,12,0,0,0,0,0,1,40"),
        "crossing-30deg": ([Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-20, 20, -20, 20), texture=solid(red)),
                            Patch([0, 0, 0], [1, 0, 0], [0, c30, s], extent=(-20, 20, -20, 20), texture=solid(blue))],
                           "8,-45,30,0,0,0,0,0,1,45"),
        "parallel-0.5zt": ([Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-20, 20, -20, 20), texture=solid(orange)),
                            Patch([0, 0, -0.5 * z_t], [1, 0, 0], [0, 1, 0], extent=(-25, 25, -25, 25), texture=solid(blue))],
                           "0,-35,30,0,0,0,0,0,1,45"),
        "parallel-2zt": ([Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-20, 20, -20, 20), texture=solid(orange)),
                          Patch([0, 0, -2 * z_t], [1, 0, 0], [0, 1, 0], extent=(-25, 25, -25, 25), texture=solid(blue))],
                         "0,-35,30,0,0,0,0,0,1,45"),
        "thin-sheet": ([Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-20, 20, -20, 20), texture=solid(orange)),
                        Patch([0, 0, -0.05], [1, 0, 0], [0, 1, 0], extent=(-20, 20, -20, 20), texture=solid(blue),
                              normal_sign=-1)],
                       "0,-35,30,0,0,0,0,0,1,45"),
        "open-boundary": ([Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], radius=15, texture=tex_checker)],
                          "0,-30,22,0,0,0,0,0,1,45"),
    }


# --- the reference ray caster -------------------------------------------------

def camera_rays(camera, width, height):
    v = [float(x) for x in camera.split(",")]
    eye, target, up, fov = np.array(v[0:3]), np.array(v[3:6]), np.array(v[6:9]), v[9]
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    eta = height / (2 * np.tan(np.radians(fov) / 2))
    return eye, f, r, u, eta


def row_rays(camera, width, height):
    """Per image row y: (y, origins, unit directions) of SUPERSAMPLE² rays per
    pixel, pixel by pixel (reshape to (width, SUPERSAMPLE², ...) to average)."""
    eye, f, r, u, eta = camera_rays(camera, width, height)
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE
    ox, oy = (a.ravel() for a in np.meshgrid(offsets, offsets))
    for y in range(height):
        px = np.repeat(np.arange(width), len(ox)) + np.tile(ox, width)
        py = y + np.tile(oy, width)
        d = f[None, :] + ((px - width / 2) / eta)[:, None] * r[None, :] - ((py - height / 2) / eta)[:, None] * u[None, :]
        d /= np.linalg.norm(d, axis=1)[:, None]
        yield y, np.repeat(eye[None, :], len(d), axis=0), d


def reference(surfaces, camera, width, height, more=None):
    """more(y, directions, best, colour): other surfaces of image row y, which
    update the row's nearest hit distances and colours in place."""
    image = np.zeros((height, width, 3))
    for y, o, d in row_rays(camera, width, height):
        best = np.full(len(d), np.inf)
        colour = np.repeat(BACKGROUND[None, :], len(d), axis=0)
        for s in surfaces:
            t, param = s.intersect(o, d)
            hit = t < best
            if hit.any():
                colour[hit] = s.colour(tuple(p[hit] for p in param))
                best[hit] = t[hit]
        if more:
            more(y, d, best, colour)
        image[y] = colour.reshape(width, SUPERSAMPLE ** 2, 3).mean(axis=1)
    return image


# --- surfels, programs, metrics ----------------------------------------------

def write_ply(path, points, normals, colours):
    n = len(points)
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\n"
              "property double x\nproperty double y\nproperty double z\n"
              "property float nx\nproperty float ny\nproperty float nz\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n" % n)
    rec = np.zeros(n, dtype=[("p", "<f8", 3), ("n", "<f4", 3), ("c", "u1", 3)])
    rec["p"], rec["n"] = points, normals
    rec["c"] = np.clip(np.round(colours * 255), 0, 255)
    with open(path, "wb") as fh:
        fh.write(header.encode())
        fh.write(rec.tobytes())


def run(args):
    return subprocess.run(args, check=True, capture_output=True, text=True).stdout


def render(tileset, mode, camera, size, repeat, png, kernel=None, shading="unlit", colour=None, lowpass=None,
           background="1,1,1", options=()):
    """surfcast-view --headless; camera None: its default framing; options: more of its arguments."""
    extra = ["--kernel-scale", str(kernel)] if kernel else []
    extra += ["--lowpass", str(lowpass)] if lowpass is not None else []
    extra += ["--color", colour] if colour else []
    extra += [f"--camera={camera}"] if camera else []
    out = run([os.path.join(BIN, "surfcast-view"), "--headless", tileset, "--size", size, "--mode", mode, "--shading",
               shading, "--background", background, "--repeat", str(repeat), "--out", png, *extra, *options])
    line = json.loads(out.strip().splitlines()[-1])
    gpu = line.get("gpu_ms")  # per pass; with --lod one number per redraw
    ms = line["cpu_ms"] if mode == "cpu-reference" else gpu["total"] if isinstance(gpu, dict) else gpu
    img = np.asarray(Image.open(png).convert("RGB")).astype(np.float64) / 255
    return img, ms, line["splats"]


def metrics(ref, img):
    psnr = peak_signal_noise_ratio(ref, img, data_range=1.0)
    ssim = structural_similarity(ref, img, channel_axis=2, data_range=1.0)
    _, mean_flip, _ = flip.evaluate(ref.astype(np.float32), img.astype(np.float32), "LDR")
    return psnr, ssim, float(mean_flip)


def write_csv(name, rows):
    """bench/report/NAME from a list of dicts with the same keys."""
    with open(os.path.join(REPORT, name), "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)


def write_markdown(name, lines):
    """bench/report/NAME from Markdown lines, and the same on stdout."""
    text = "\n".join(lines) + "\n"
    with open(os.path.join(REPORT, name), "w") as fh:
        fh.write(text)
    print(text)


def montage(name, ref, images):
    tiles = [("reference", ref)] + images
    h, w = ref.shape[:2]
    sheet = Image.new("RGB", (w * 4, h * 2), "white")
    from PIL import ImageDraw
    draw = ImageDraw.Draw(sheet)
    for k, (label, img) in enumerate(tiles[:8]):
        x, y = (k % 4) * w, (k // 4) * h
        sheet.paste(Image.fromarray((np.clip(img, 0, 1) * 255).astype(np.uint8)), (x, y))
        draw.rectangle([x, y, x + 7 * len(label) + 6, y + 14], fill="white")
        draw.text((x + 3, y + 2), label, fill="black")
    sheet.save(os.path.join(REPORT, f"montage-{name}.png"))


def chart(rows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for k, mode in enumerate(MODES):
        sel = [r for r in rows if r["mode"] == mode]
        ax.scatter([r["ms"] for r in sel], [r["flip"] for r in sel], s=18, alpha=0.5, color=f"C{k}")
        ax.scatter([np.median([r["ms"] for r in sel])], [np.mean([r["flip"] for r in sel])], s=120, marker="*",
                   color=f"C{k}", edgecolor="k", label=f"{mode} (median ms, mean FLIP)")
    ax.set_xscale("log")
    ax.set_xlabel("frame time, ms (GPU timestamps on lavapipe; CPU for cpu-reference)")
    ax.set_ylabel("mean FLIP against the 16x16 ray-cast reference (lower is better)")
    ax.set_title("Speed against accuracy, per scene (dots) and per mode (stars)")
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(os.path.join(REPORT, "accuracy_speed.png"), dpi=110)


def quantization_sweep(name, ply, camera, ref, size, tmp):
    out = []
    for option, value in QUANTIZATION:
        label = f"--{option}" + ("" if value is None else f" {value}")
        tileset = os.path.join(tmp, f"{name}-q")
        shutil.rmtree(tileset, ignore_errors=True)
        run([os.path.join(BIN, "surfcast-build"), "-q", "--weights", "analytic", ply, "-o", tileset, f"--{option}"] +
            ([] if value is None else [str(value)]))
        info = json.load(open(os.path.join(tileset, "tileset.json")))
        level = max(info["levels"] - 2, 0)  # the finest resampled level
        geo = json.loads(run([os.path.join(BIN, "surfcast-geom-error"), tileset, str(level), *GEOMETRY[name]]))
        img, ms, splats = render_level(tileset, camera, size, level, os.path.join(tmp, "q.png"))
        _, _, fl = metrics(ref, img)
        out.append({"scene": name, "option": label, "level": level, "surfels": info["surfels"],
                    "bytes": os.path.getsize(os.path.join(tileset, "blocks.bin")), "rms": geo["rms"],
                    "normal_deg": geo["normal_rms_degrees"], "flip": fl})
        print(f"{name} {label}: {out[-1]['bytes']} bytes, RMS {geo['rms']:.2e}, FLIP {fl:.4f}", file=sys.stderr)
    return out


def mesh_view(mesh, size, tmp, shading="lambert"):
    """The mesh's vertices built as surfels, a camera on it, and the mesh's own reference image."""
    src = os.path.join(DATA, mesh + ".ply")
    tileset = os.path.join(tmp, "mesh-" + mesh)
    if not os.path.exists(tileset):
        run([os.path.join(BIN, "surfcast-build"), "-q", "--weights", "analytic", "--vertices-only", src, "-o", tileset])
    info = json.load(open(os.path.join(tileset, "tileset.json")))
    lo, hi = np.array(info["bounds"]["min"]), np.array(info["bounds"]["max"])
    centre, diag = (lo + hi) / 2, np.linalg.norm(hi - lo)
    d = np.array([0.3, 0.35, 1.0])
    d /= np.linalg.norm(d)
    eye = centre + d * 1.4 * diag
    camera = ",".join(f"{v:.9g}" for v in [*eye, *centre]) + ",0,1,0,40"
    ref_png = os.path.join(tmp, f"mesh-ref-{shading}.png")
    run([os.path.join(BIN, "surfcast-mesh-reference"), src, f"--camera={camera}", "--size", size, "--shading", shading,
         "--out", ref_png])
    ref = np.asarray(Image.open(ref_png).convert("RGB")).astype(np.float64) / 255
    return src, tileset, camera, ref


# The model sweep on the scanned meshes: irregular vertex sampling (where a
# per-surfel radius can matter) and shaded normals (where normal bits show).
# Normal bits: of each octahedral coordinate (the default 8).
MESH_MODEL = [("defaults", []), ("no-radius", ["--no-radius"])] + \
             [(f"normal-bits {n}", ["--normal-bits", str(n)]) for n in (6, 7, 9, 10, 12)]


def mesh_model_sweep(mesh, size, tmp):
    out = []
    for shading in ("lambert", "phong"):
        src, _, camera, ref = mesh_view(mesh, size, tmp, shading)
        for label, options in MESH_MODEL:
            tileset = os.path.join(tmp, f"mesh-{mesh}-model")
            shutil.rmtree(tileset, ignore_errors=True)
            run([os.path.join(BIN, "surfcast-build"), "-q", "--weights", "analytic", "--vertices-only", src, "-o", tileset, *options])
            img, ms, splats = render(tileset, "ewa-pixel", camera, size, 1, os.path.join(tmp, "m.png"), shading=shading,
                                     colour="0.8,0.8,0.8")
            psnr, ssim, fl = metrics(ref, img)
            out.append({"scene": "mesh-" + mesh, "option": label, "shading": shading,
                        "bytes": os.path.getsize(os.path.join(tileset, "blocks.bin")), "psnr": psnr, "flip": fl})
            print(f"mesh-{mesh} {label} {shading}: {out[-1]['bytes']} bytes, PSNR {psnr:.2f}, FLIP {fl:.4f}",
                  file=sys.stderr)
    return out


def pinholes(img, background=1.0):
    """Background pixels with at least 6 of their 8 neighbours covered."""
    bg = np.all(np.abs(img - background) < 1e-6, axis=2)
    covered = (~bg).astype(int)
    p = np.pad(covered, 1)
    around = sum(p[1 + dy:p.shape[0] - 1 + dy, 1 + dx:p.shape[1] - 1 + dx]
                 for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx)
    return int(np.sum(bg & (around >= 6))), int(covered.sum())


def scan_radius_study(tmp, size="640x480"):
    """--no-radius on an irregular real scan (CSite1: UTM LiDAR), which has no
    reference surface: bytes, pinholes and coverage with and without radii,
    and FLIP between the two renders (every leaf, default camera)."""
    src = os.path.join(DATA, "CSite1_red1-utm.pcd")
    out, images = [], {}
    for label, options in (("radii (default)", []), ("no-radius", ["--no-radius"])):
        tileset = os.path.join(tmp, "scan-radius")
        shutil.rmtree(tileset, ignore_errors=True)
        run([os.path.join(BIN, "surfcast-build"), "-q", "--weights", "analytic", src, "-o", tileset, *options])
        png = os.path.join(tmp, "scan.png")
        run([os.path.join(BIN, "surfcast-view"), "--headless", tileset, "--size", size, "--out", png])
        img = np.asarray(Image.open(png).convert("RGB")).astype(np.float64) / 255
        holes, covered = pinholes(img)
        images[label] = img
        out.append({"scene": "CSite1_red1-utm.pcd", "option": label,
                    "bytes": os.path.getsize(os.path.join(tileset, "blocks.bin")), "pinholes": holes, "covered": covered})
    out[1]["flip_vs_default"] = metrics(images["radii (default)"], images["no-radius"])[2]
    out[0]["flip_vs_default"] = 0.0
    return out


def radius_synthetic_study(size, tmp):
    """--no-radius where it matters and the truth is known: a checkerboard
    plane sampled 10x more densely on one half (0.05 against 0.5 units), so
    the nodes across the jump are irregular and store radii. Both builds
    rendered with ewa-pixel against the 16x16 ray-cast reference."""
    dark, light = np.array([0.1, 0.1, 0.12]), np.array([0.92, 0.9, 0.85])
    # Patch-local (a, b) shifted by the centre's x: one continuous checker.
    left = Patch([-8, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-8, 8, -20, 20), spacing=0.5,
                 texture=lambda a, b: checker(a - 8, b, 4.0, dark, light))
    right = Patch([8, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-8, 8, -20, 20), spacing=0.05,
                  texture=lambda a, b: checker(a + 8, b, 4.0, dark, light))
    camera = "0,-22,14,0,2,0,0,0,1,50"
    width, height = (int(v) for v in size.split("x"))
    ref = reference([left, right], camera, width, height)
    rng = np.random.default_rng(2)
    pts, nrm, col = (np.concatenate(x) for x in zip(*(p.samples(rng) for p in (left, right))))
    ply = os.path.join(tmp, "density-jump.ply")
    write_ply(ply, pts, nrm, col)
    out = []
    for label, options in (("radii (default)", []), ("no-radius", ["--no-radius"])):
        tileset = os.path.join(tmp, "density-jump")
        shutil.rmtree(tileset, ignore_errors=True)
        run([os.path.join(BIN, "surfcast-build"), "-q", "--weights", "analytic", ply, "-o", tileset, *options])
        img, ms, splats = render(tileset, "ewa-pixel", camera, size, 1, os.path.join(tmp, "dj.png"))
        psnr, ssim, fl = metrics(ref, img)
        holes, covered = pinholes(img)
        out.append({"scene": "density-jump 10x", "option": label,
                    "bytes": os.path.getsize(os.path.join(tileset, "blocks.bin")), "psnr": psnr, "flip": fl,
                    "pinholes": holes, "covered": covered})
        print(f"density-jump {label}: {out[-1]['bytes']} bytes, PSNR {psnr:.2f}, FLIP {fl:.4f}, {holes} pinholes",
              file=sys.stderr)
    return out


def write_mesh_model(rows, scan=(), synthetic=()):
    write_csv("mesh_model.csv", rows)
    lines = ["Model sweep on the scanned meshes (vertices as surfels, every leaf, ewa-pixel, grey, against the mesh "
             "rasterized 4x4 with the same shading):", "",
             "| mesh | option | shading | blocks bytes | PSNR dB | FLIP |", "|---|---|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['option']} | {r['shading']} | {r['bytes']} | {r['psnr']:.2f} | {r['flip']:.4f} |")
    if synthetic:
        lines += ["", "Per-surfel radii on a synthetic density jump (ray-cast reference, ewa-pixel):", "",
                  "| scene | option | blocks bytes | PSNR dB | FLIP | covered pixels | pinholes |",
                  "|---|---|---:|---:|---:|---:|---:|"]
        for r in synthetic:
            lines.append(f"| {r['scene']} | {r['option']} | {r['bytes']} | {r['psnr']:.2f} | {r['flip']:.4f} | "
                         f"{r['covered']} | {r['pinholes']} |")
    if scan:
        lines += ["", "Per-surfel radii on an irregular scan (no reference surface; every leaf, default camera, 640x480):", "",
                  "| scan | option | blocks bytes | covered pixels | pinholes | FLIP against radii |", "|---|---|---:|---:|---:|---:|"]
        for r in scan:
            lines.append(f"| {r['scene']} | {r['option']} | {r['bytes']} | {r['covered']} | {r['pinholes']} | "
                         f"{r['flip_vs_default']:.4f} |")
    write_markdown("mesh_model.md", lines)


def mesh_scene(mesh, size, repeat, tmp):
    _, tileset, camera, ref = mesh_view(mesh, size, tmp)
    out, images = [], []
    for mode in MODES:
        img, ms, splats = render(tileset, mode, camera, size, 1 if mode == "cpu-reference" else repeat,
                                 os.path.join(tmp, "frame.png"), shading="lambert", colour="0.8,0.8,0.8")
        psnr, ssim, fl = metrics(ref, img)
        out.append({"scene": "mesh-" + mesh, "mode": mode, "kernel": "", "splats": splats, "ms": ms, "psnr": psnr,
                    "ssim": ssim, "flip": fl})
        images.append((mode, img))
        print(f"mesh-{mesh} {mode}: {ms:.1f} ms, PSNR {psnr:.2f}, FLIP {fl:.4f}", file=sys.stderr)
    montage("mesh-" + mesh, ref, images)
    return out, lowpass_sweep("mesh-" + mesh, tileset, camera, ref, size, tmp, shading="lambert", colour="0.8,0.8,0.8")


def lowpass_sweep(name, tileset, camera, ref, size, tmp, shading="unlit", colour=None):
    out = []
    for v in LOWPASS:
        img, ms, splats = render(tileset, "ewa-pixel", camera, size, 1, os.path.join(tmp, "lp.png"), shading=shading,
                                 colour=colour, lowpass=v)
        psnr, ssim, fl = metrics(ref, img)
        out.append({"scene": name, "lowpass": v, "psnr": psnr, "ssim": ssim, "flip": fl})
    return out


def render_level(tileset, camera, size, level, png):
    run([os.path.join(BIN, "surfcast-view"), "--headless", tileset, f"--camera={camera}", "--size", size, "--level",
         str(level), "--shading", "unlit", "--background", "1,1,1", "--out", png])
    return np.asarray(Image.open(png).convert("RGB")).astype(np.float64) / 255, 0, 0


def model_chart(model):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, metric, label in [(axes[0], "flip", "mean FLIP (ewa-pixel, resampled level)"),
                              (axes[1], "rms", "RMS distance to the true surface")]:
        for k, scene in enumerate(sorted({r["scene"] for r in model})):
            for r in (r for r in model if r["scene"] == scene):
                ax.scatter(r["bytes"] / r["surfels"], r[metric], color=f"C{k}", s=20)
                ax.annotate(r["option"].replace("--", ""), (r["bytes"] / r["surfels"], r[metric]), fontsize=6)
        ax.set_xlabel("block bytes per surfel")
        ax.set_ylabel(label)
        if metric == "rms":
            ax.set_yscale("log")
    axes[0].set_title("Model size against image error")
    axes[1].set_title("Model size against geometric error")
    fig.tight_layout()
    fig.savefig(os.path.join(REPORT, "model_size.png"), dpi=110)


def kernel_chart(sweep):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name in sorted({r["scene"] for r in sweep}):
        sel = sorted((r for r in sweep if r["scene"] == name), key=lambda r: r["kernel"])
        ax.plot([r["kernel"] for r in sel], [r["flip"] for r in sel], marker="o", label=name)
    ax.set_xlabel("kernel scale k (V^r = (k h)^2 I)")
    ax.set_ylabel("mean FLIP (ewa-pixel)")
    ax.set_title("Reconstruction kernel width against accuracy")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(REPORT, "kernel_scale.png"), dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scenes", default="", help="comma-separated subset")
    ap.add_argument("--mesh-model-only", action="store_true",
                    help="only the model sweep on the scanned meshes (mesh_model.csv, mesh_model.md)")
    args = ap.parse_args()
    if args.mesh_model_only:
        os.makedirs(REPORT, exist_ok=True)
        with tempfile.TemporaryDirectory() as tmp:
            write_mesh_model([r for mesh in MESHES for r in mesh_model_sweep(mesh, args.size, tmp)], scan_radius_study(tmp),
                             radius_synthetic_study(args.size, tmp))
        return
    width, height = (int(v) for v in args.size.split("x"))
    os.makedirs(REPORT, exist_ok=True)
    rng = np.random.default_rng(1)
    rows, sweep, model, lowpass, mesh_model, scan, synthetic = [], [], [], [], [], [], []
    wanted = set(args.scenes.split(",")) if args.scenes else None
    with tempfile.TemporaryDirectory() as tmp:
        for name, (surfaces, camera) in scenes().items():
            if wanted and name not in wanted:
                continue
            ref = reference(surfaces, camera, width, height)
            pts, nrm, col = (np.concatenate(x) for x in zip(*(s.samples(rng) for s in surfaces)))
            ply = os.path.join(tmp, name + ".ply")
            write_ply(ply, pts, nrm, col)
            tileset = os.path.join(tmp, name)
            run([os.path.join(BIN, "surfcast-build"), "-q", "--weights", "analytic", ply, "-o", tileset])
            images = []
            for mode in MODES:
                img, ms, splats = render(tileset, mode, camera, args.size, 1 if mode == "cpu-reference" else args.repeat,
                                         os.path.join(tmp, "frame.png"))
                psnr, ssim, fl = metrics(ref, img)
                rows.append({"scene": name, "mode": mode, "kernel": "", "splats": splats, "ms": ms, "psnr": psnr,
                             "ssim": ssim, "flip": fl})
                images.append((mode, img))
                print(f"{name} {mode}: {ms:.1f} ms, PSNR {psnr:.2f}, SSIM {ssim:.3f}, FLIP {fl:.4f}", file=sys.stderr)
            montage(name, ref, images)
            if name in GEOMETRY:
                model.extend(quantization_sweep(name, ply, camera, ref, args.size, tmp))
            for k in KERNEL_SCALES:
                img, ms, splats = render(tileset, "ewa-pixel", camera, args.size, 1, os.path.join(tmp, "frame.png"), k)
                psnr, ssim, fl = metrics(ref, img)
                sweep.append({"scene": name, "mode": "ewa-pixel", "kernel": k, "splats": splats, "ms": ms, "psnr": psnr,
                              "ssim": ssim, "flip": fl})
            lowpass.extend(lowpass_sweep(name, tileset, camera, ref, args.size, tmp))
        for mesh in MESHES if not wanted else [m for m in MESHES if "mesh-" + m in wanted]:
            mesh_rows, mesh_lowpass = mesh_scene(mesh, args.size, args.repeat, tmp)
            rows.extend(mesh_rows)
            lowpass.extend(mesh_lowpass)
            mesh_model.extend(mesh_model_sweep(mesh, args.size, tmp))
        if mesh_model:
            scan, synthetic = scan_radius_study(tmp), radius_synthetic_study(args.size, tmp)
    write_csv("accuracy.csv", rows + sweep)
    chart(rows)
    if sweep:
        kernel_chart(sweep)
    if mesh_model:
        write_mesh_model(mesh_model, scan, synthetic)
    if model:
        model_chart(model)
        write_csv("model.csv", model)
    lines = [f"Scenes at {args.size}, reference 16x16 ray-cast; time = median of {args.repeat} (GPU), one run (CPU).", "",
             "| scene | mode | splats | ms | PSNR dB | SSIM | FLIP |", "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['mode']} | {r['splats']} | {r['ms']:.1f} | {r['psnr']:.2f} | {r['ssim']:.3f} | {r['flip']:.4f} |")
    lines += ["", "| mode | median ms | mean PSNR dB | mean SSIM | mean FLIP |", "|---|---:|---:|---:|---:|"]
    for mode in MODES:
        sel = [r for r in rows if r["mode"] == mode]
        lines.append(f"| {mode} | {np.median([r['ms'] for r in sel]):.1f} | {np.mean([r['psnr'] for r in sel]):.2f} | "
                     f"{np.mean([r['ssim'] for r in sel]):.3f} | {np.mean([r['flip'] for r in sel]):.4f} |")
    if sweep:
        lines += ["", "Kernel scale sweep (ewa-pixel, V^r = (k h)^2 I), mean over the synthetic scenes:", "",
                  "| k | mean PSNR dB | mean SSIM | mean FLIP | worst scene FLIP |", "|---:|---:|---:|---:|---:|"]
    for k in KERNEL_SCALES if sweep else []:
        sel = [r for r in sweep if r["kernel"] == k]
        lines.append(f"| {k} | {np.mean([r['psnr'] for r in sel]):.2f} | {np.mean([r['ssim'] for r in sel]):.3f} | "
                     f"{np.mean([r['flip'] for r in sel]):.4f} | {max(r['flip'] for r in sel):.4f} |")
    if lowpass:
        scenes_lp = sorted({r["scene"] for r in lowpass})
        lines += ["", "Low-pass filter sweep (ewa-pixel, V^h = v I px^2), FLIP per scene:", "",
                  "| scene | " + " | ".join(f"v = {v}" for v in LOWPASS) + " |", "|---|" + "---:|" * len(LOWPASS)]
        for sc in scenes_lp:
            vals = {r["lowpass"]: r["flip"] for r in lowpass if r["scene"] == sc}
            lines.append(f"| {sc} | " + " | ".join(f"{vals[v]:.4f}" for v in LOWPASS) + " |")
        lines.append("| mean | " + " | ".join(f"{np.mean([r['flip'] for r in lowpass if r['lowpass'] == v]):.4f}"
                                                for v in LOWPASS) + " |")
    if model:
        lines += ["", "Model sweep (one option changed from the defaults; a resampled level rendered with ewa-pixel):", "",
                  "| scene | option | level | blocks bytes (all levels) | bytes/surfel | RMS distance (level) | normal RMS deg | FLIP (level) |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
        for r in model:
            lines.append(f"| {r['scene']} | {r['option']} | {r['level']} | {r['bytes']} | {r['bytes'] / r['surfels']:.2f} | "
                         f"{r['rms']:.2e} | {r['normal_deg']:.2f} | {r['flip']:.4f} |")
    write_markdown("accuracy.md", lines)


if __name__ == "__main__":
    main()
