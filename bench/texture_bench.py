#!/usr/bin/env python3
"""Texture acquisition (Zwicker et al. 2001, §5): --texture-filter nearest, ewa
and optimal against exact references, under zoom and at grazing angles.

The accuracy harness's procedural textures (accuracy_bench.py: band-limited
checkerboards and a zone plate) are written as textured meshes, a mesh and a
PNG rasterized from the same functions at 16 texels per unit (9 texels per
wavelength of the checkerboard's highest harmonic), plus an OBJ and MTL.
surfcast-build samples them at 0.5 units (uniform random points: irregular,
as in the paper's Figure 6) with each --texture-filter; surfcast-view renders
them (ewa-pixel, unlit) and the harness's ray caster gives the reference
(16 x 16 samples per pixel of the analytic texture).

Views:
- zoom: the checkerboard plane seen head-on from distances at which one
  sampling step (0.5 units) spans 0.5 to 16 pixels, from minification to
  strong magnification, every leaf drawn;
- lod: the same from 1/8 to 1 pixel per step with --lod 1, so the coarser
  levels (--capacity 2000 gives the plane four) carry the texture;
- grazing: the same plane at 4 pixels per step, seen from 90 down to 10
  degrees above it;
- the harness's own views of the zone plate and the textured sphere;
- the shared textured dragon (its default spacing, one leaf per texel) at
  three zooms, against the mesh itself rendered with its texture by
  surfcast-mesh-reference --colors (16 samples per pixel, trilinear mip
  filtering), over the pixels both cover and whose neighbours both cover.

Errors are over the pixels that see the surface's interior (silhouettes are
edge antialiasing's business): mean FLIP (LDR) and PSNR. Build time and
bytes per method come from surfcast-build's own summary.

Writes bench/report/texture.csv, texture.md, texture_zoom.png (FLIP and PSNR
against pixels per sampling step, one line per method: the paper's Figure 6
claim as numbers) and figure6.png (the magnified checkerboard: reference,
optimal, ewa, nearest).

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/texture_bench.py [--size 320x240]
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image, ImageDraw

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import accuracy_bench as ab  # noqa: E402

METHODS = ["nearest", "ewa", "optimal"]
TEXELS_PER_UNIT = 16
STEPS_PX = [0.5, 1, 2, 4, 8, 16]       # zoom: pixels per sampling step
LOD_STEPS_PX = [0.125, 0.25, 0.5, 1]   # minified with --lod 1: the coarse levels drawn
ELEVATIONS = [90, 60, 45, 30, 20, 10]  # grazing: degrees above the plane
FOV = 40.0
DARK, LIGHT = np.array([0.1, 0.1, 0.12]), np.array([0.92, 0.9, 0.85])


def plane_texture(a, b):
    return ab.checker(a, b, 4.0, DARK, LIGHT)


def zone_texture(a, b):
    return (0.5 + 0.5 * np.cos(0.052 * (a * a + b * b)))[:, None] * (LIGHT - DARK) + DARK


def sphere_texture(phi, theta):
    return ab.checker(phi * 12 / np.pi, theta * 6 / np.pi, 2.0, DARK, LIGHT)


def write_png(path, rgb):
    Image.fromarray(np.clip(np.round(rgb * 255), 0, 255).astype(np.uint8)).save(path)


def write_obj(folder, name, vertices, uvs, faces, normals, texture):
    """OBJ + MTL + PNG; faces index vertices, uvs and normals alike (1-based in the file)."""
    write_png(os.path.join(folder, name + ".png"), texture)
    with open(os.path.join(folder, name + ".mtl"), "w") as fh:
        fh.write(f"newmtl surface\nKd 1 1 1\nmap_Kd {name}.png\n")
    with open(os.path.join(folder, name + ".obj"), "w") as fh:
        fh.write(f"mtllib {name}.mtl\n")
        fh.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in vertices)
        fh.writelines(f"vt {u:.9g} {v:.9g}\n" for u, v in uvs)
        fh.writelines(f"vn {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in normals)
        fh.write("usemtl surface\n")
        fh.writelines("f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in f) + "\n" for f in faces)
    return os.path.join(folder, name + ".obj")


def plane_mesh(folder, name, extent, texture):
    """A rectangle in z = 0, normal +z, its texture rasterized at texel centres
    (row 0 at the top: v up, as OBJ has it)."""
    a0, a1, b0, b1 = extent
    w, h = int(round((a1 - a0) * TEXELS_PER_UNIT)), int(round((b1 - b0) * TEXELS_PER_UNIT))
    a = a0 + (np.arange(w) + 0.5) / TEXELS_PER_UNIT
    b = b1 - (np.arange(h) + 0.5) / TEXELS_PER_UNIT
    A, B = np.meshgrid(a, b)
    image = texture(A.ravel(), B.ravel()).reshape(h, w, 3)
    vertices = [(a0, b0, 0), (a1, b0, 0), (a1, b1, 0), (a0, b1, 0)]
    uvs = [(0, 0), (1, 0), (1, 1), (0, 1)]
    return write_obj(folder, name, vertices, uvs, [(0, 1, 2), (0, 2, 3)], [(0, 0, 1)] * 4, image)


def sphere_mesh(folder, name, radius, texture, rings=128, segments=256):
    """A UV sphere about the origin; the texture is equirectangular in the
    harness's angles (phi = atan2(y, x) from -pi, theta from +z), with a
    seam of duplicated vertices at phi = +-pi."""
    w, h = 2048, 1024
    phi = -np.pi + (np.arange(w) + 0.5) / w * 2 * np.pi
    theta = (np.arange(h) + 0.5) / h * np.pi
    P, T = np.meshgrid(phi, theta)
    image = texture(P.ravel(), T.ravel()).reshape(h, w, 3)
    vertices, uvs, normals, index = [], [], [], {}
    for i in range(rings + 1):
        t = np.pi * i / rings
        for j in range(segments + 1):
            p = -np.pi + 2 * np.pi * j / segments
            n = (np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t))
            index[i, j] = len(vertices)
            vertices.append(tuple(radius * c for c in n))
            normals.append(n)
            uvs.append((j / segments, 1 - i / rings))
    faces = []
    for i in range(rings):
        for j in range(segments):
            a, b, c, d = index[i, j], index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]
            if i > 0:
                faces.append((a, b, d))
            if i < rings - 1:
                faces.append((b, c, d))
    return write_obj(folder, name, vertices, uvs, faces, normals, image)


def camera_string(eye, target, up):
    return ",".join(f"{v:.6g}" for v in (*eye, *target, *up, FOV))


def interior_mask(surface, camera, width, height):
    """Pixels whose every corner ray hits `surface` (a shrunk copy of the scene)."""
    eye, f, r, u, eta = ab.camera_rays(camera, width, height)
    hit = np.ones((height, width), bool)
    for ox in (0.0, 1.0):
        for oy in (0.0, 1.0):
            px, py = np.meshgrid(np.arange(width) + ox, np.arange(height) + oy)
            d = f[None, :] + ((px.ravel() - width / 2) / eta)[:, None] * r[None, :] - \
                ((py.ravel() - height / 2) / eta)[:, None] * u[None, :]
            d /= np.linalg.norm(d, axis=1)[:, None]
            t, _ = surface.intersect(np.repeat(eye[None, :], len(d), axis=0), d)
            hit &= np.isfinite(t).reshape(height, width)
    return hit


def masked_metrics(ref, img, mask):
    import flip_evaluator as flip
    error_map, _, _ = flip.evaluate(ref.astype(np.float32), img.astype(np.float32), "LDR")
    mse = float(((ref - img) ** 2)[mask].mean())
    return float(error_map[mask].mean()), 10 * np.log10(1 / max(mse, 1e-12))


def summary(text):
    """Time, bytes, surfels and the least-squares solves from surfcast-build's summary."""
    fit = re.search(r"CG iterations mean ([0-9.]+) max ([0-9]+), largest residual ([0-9.e-]+)", text)
    return {"seconds": float(re.search(r"total ([0-9.]+) s", text).group(1)),
            "texture_s": float(re.search(r"textures ([0-9.]+),", text).group(1)),
            "blocks": int(re.search(r"blocks ([0-9]+)", text).group(1)),
            "surfels": int(re.search(r"surfels: ([0-9]+)", text).group(1)),
            "cg_mean": float(fit.group(1)) if fit else "", "cg_max": int(fit.group(2)) if fit else ""}


def build(obj, method, out):
    p = subprocess.run([os.path.join(ab.BIN, "surfcast-build"), obj, "-o", out, "--mesh-spacing", str(ab.SPACING),
                        "--texture-filter", method, "--threads", "2", "--capacity", "2000"], capture_output=True, text=True,
                       check=True)
    return summary(p.stdout + p.stderr)


DRAGON = os.path.join(ab.DATA, "fg_spkMgDragon", "fg_spkMgDragon.obj")
DRAGON_FOVS = [40, 10, 2.5]  # the whole dragon, then 4x and 16x magnified


def dragon_views(tmp, size, rows, builds):
    if not os.path.exists(DRAGON):
        sys.exit(f"{DRAGON} is missing: the shared data must sit beside the repository (../shared/data)")
    sets = {}
    for method in METHODS:
        sets[method] = os.path.join(tmp, f"dragon-{method}")
        p = subprocess.run([os.path.join(ab.BIN, "surfcast-build"), DRAGON, "-o", sets[method], "--texture-filter", method,
                            "--threads", "2"], capture_output=True, text=True, check=True)
        builds.append({"scene": "dragon", "method": method, **summary(p.stdout + p.stderr)})
        print(f"build dragon {method}: {builds[-1]}", file=sys.stderr)
    for fov in DRAGON_FOVS:
        camera = f"0.0,0.05,0.15,0.005,0.04,0,0,1,0,{fov}"
        png = os.path.join(tmp, "mesh.png")
        ab.run([os.path.join(ab.BIN, "surfcast-mesh-reference"), DRAGON, "--camera", camera, "--size", size, "--shading", "unlit",
                "--colors", "--out", png])
        ref = np.asarray(Image.open(png).convert("RGB")).astype(np.float64) / 255
        for method in METHODS:
            img = ab.render(sets[method], "ewa-pixel", camera, size, 1, os.path.join(tmp, "frame.png"))[0]
            covered = (np.abs(ref - ref[0, 0]).sum(2) > 0.01) & (np.abs(img - img[0, 0]).sum(2) > 0.01)
            inner = covered.copy()
            inner[1:-1, 1:-1] = covered[1:-1, 1:-1] & covered[:-2, 1:-1] & covered[2:, 1:-1] & covered[1:-1, :-2] & covered[1:-1, 2:]
            inner[0, :] = inner[-1, :] = inner[:, 0] = inner[:, -1] = False
            fl, psnr = masked_metrics(ref, img, inner)
            rows.append({"scene": "dragon", "series": "dragon", "x": fov, "method": method, "flip": fl, "psnr": psnr,
                         "pixels": int(inner.sum())})
            print(f"dragon fov {fov} {method}: FLIP {fl:.4f} PSNR {psnr:.2f}", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x240")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    eta = height / (2 * np.tan(np.radians(FOV) / 2))
    os.makedirs(ab.REPORT, exist_ok=True)
    rows, builds, figure = [], [], {}
    with tempfile.TemporaryDirectory() as tmp:
        plane_extent = (-40, 40, -40, 40)
        scenes = {
            "checker": (plane_mesh(tmp, "checker", plane_extent, plane_texture),
                        ab.Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=plane_extent, texture=plane_texture),
                        ab.Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-39, 39, -39, 39))),
            "zone-plate": (plane_mesh(tmp, "zone", (-30, 30, -30, 30), zone_texture),
                           ab.Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-30, 30, -30, 30), texture=zone_texture),
                           ab.Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-29, 29, -29, 29))),
            "textured-sphere": (sphere_mesh(tmp, "sphere", 10, sphere_texture),
                                ab.Sphere([0, 0, 0], 10, sphere_texture), ab.Sphere([0, 0, 0], 9.6, None)),
        }
        views = []  # (scene, series, x, camera)
        for s in STEPS_PX:
            d = ab.SPACING * eta / s
            views.append(("checker", "zoom", s, camera_string((0.3, 0.2, d), (0.3, 0.2, 0), (0, 1, 0))))
        for s in LOD_STEPS_PX:
            d = ab.SPACING * eta / s
            views.append(("checker", "lod", s, camera_string((0.3, 0.2, d), (0.3, 0.2, 0), (0, 1, 0))))
        for e in ELEVATIONS:
            d = ab.SPACING * eta / 4
            el = np.radians(e)
            up = (0, 1, 0) if e == 90 else (0, 0, 1)
            views.append(("checker", "grazing", e, camera_string((0.3, 0.2 - d * np.cos(el), d * np.sin(el)), (0.3, 0.2, 0), up)))
        views.append(("zone-plate", "view", 0, "0,-30,55,0,0,0,0,0,1,50"))
        views.append(("textured-sphere", "view", 0, "0,-35,12,0,0,0,0,0,1,40"))
        for name, (obj, surface, shrunk) in scenes.items():
            sets = {}
            for method in METHODS:
                sets[method] = os.path.join(tmp, f"{name}-{method}")
                info = build(obj, method, sets[method])
                builds.append({"scene": name, "method": method, **info})
                print(f"build {name} {method}: {info}", file=sys.stderr)
            for scene, series, x, camera in views:
                if scene != name:
                    continue
                ref = ab.reference([surface], camera, width, height)
                mask = interior_mask(shrunk, camera, width, height)
                for method in METHODS:
                    img = ab.render(sets[method], "ewa-pixel", camera, args.size, 1, os.path.join(tmp, "frame.png"),
                                    options=["--lod", "1"] if series == "lod" else [])[0]
                    fl, psnr = masked_metrics(ref, img, mask)
                    rows.append({"scene": scene, "series": series, "x": x, "method": method, "flip": fl, "psnr": psnr,
                                 "pixels": int(mask.sum())})
                    print(f"{scene} {series} {x} {method}: FLIP {fl:.4f} PSNR {psnr:.2f} ({mask.sum()} px)", file=sys.stderr)
                    if series == "zoom" and x == STEPS_PX[-1]:
                        figure[method] = img
                if series == "zoom" and x == STEPS_PX[-1]:
                    figure["reference"] = ref
        dragon_views(tmp, args.size, rows, builds)
    ab.write_csv("texture.csv", rows)
    ab.write_csv("texture_builds.csv", builds)
    chart(rows)
    figure6(figure)
    report(rows, builds)


def chart(rows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for k, method in enumerate(METHODS):
        zoom = [r for r in rows if r["series"] == "zoom" and r["method"] == method]
        graze = [r for r in rows if r["series"] == "grazing" and r["method"] == method]
        lod = [r for r in rows if r["series"] == "lod" and r["method"] == method]
        axes[0].plot([r["x"] for r in zoom], [r["flip"] for r in zoom], "o-", color=f"C{k}", label=method)
        axes[1].plot([r["x"] for r in zoom], [r["psnr"] for r in zoom], "o-", color=f"C{k}", label=method)
        axes[0].plot([r["x"] for r in lod], [r["flip"] for r in lod], "s--", color=f"C{k}", label=f"{method}, --lod 1")
        axes[1].plot([r["x"] for r in lod], [r["psnr"] for r in lod], "s--", color=f"C{k}", label=f"{method}, --lod 1")
        axes[2].plot([r["x"] for r in graze], [r["flip"] for r in graze], "o-", color=f"C{k}", label=method)
    for ax in axes[:2]:
        ax.set_xscale("log", base=2)
        ax.set_xlabel("pixels per sampling step (zoom: minified left, magnified right)")
    axes[0].set_ylabel("mean FLIP (lower is better)")
    axes[1].set_ylabel("PSNR, dB (higher is better)")
    axes[2].set_xlabel("camera elevation above the plane, degrees (4 px per step)")
    axes[2].set_ylabel("mean FLIP")
    axes[2].invert_xaxis()
    for ax in axes:
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle("Textured checkerboard, surfels at 0.5 units, against a 16x16 ray-cast reference (--texture-filter)")
    fig.tight_layout()
    fig.savefig(os.path.join(ab.REPORT, "texture_zoom.png"), dpi=100)


def figure6(images):
    if len(images) < 4:
        return
    order = ["reference", "optimal", "ewa", "nearest"]
    h, w = images["reference"].shape[:2]
    sheet = Image.new("RGB", (w * 4, h), "white")
    draw = ImageDraw.Draw(sheet)
    for k, label in enumerate(order):
        sheet.paste(Image.fromarray((np.clip(images[label], 0, 1) * 255).astype(np.uint8)), (k * w, 0))
        draw.rectangle([k * w, 0, k * w + 7 * len(label) + 6, 14], fill="white")
        draw.text((k * w + 3, 2), label, fill="black")
    sheet.save(os.path.join(ab.REPORT, "figure6.png"))


def report(rows, builds):
    lines = ["| view | " + " | ".join(f"{m} FLIP / PSNR" for m in METHODS) + " |", "|---|" + "---:|" * len(METHODS)]
    keys = []
    for r in rows:
        k = (r["scene"], r["series"], r["x"])
        if k not in keys:
            keys.append(k)
    for scene, series, x in keys:
        label = {"zoom": f"checker, {x} px per step", "lod": f"checker, {x} px per step, --lod 1",
                 "grazing": f"checker, {x}° elevation", "dragon": f"dragon, fov {x}°"}.get(series, scene)
        cells = []
        for m in METHODS:
            r = next(r for r in rows if (r["scene"], r["series"], r["x"], r["method"]) == (scene, series, x, m))
            cells.append(f"{r['flip']:.4f} / {r['psnr']:.2f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += ["", "| scene | method | surfels | blocks bytes | build s | texture step (thread-s) | CG iterations mean / max |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for b in builds:
        cg = f"{b['cg_mean']} / {b['cg_max']}" if b["cg_mean"] != "" else ""
        lines.append(f"| {b['scene']} | {b['method']} | {b['surfels']} | {b['blocks']} | {b['seconds']:.2f} | "
                     f"{b['texture_s']:.2f} | {cg} |")
    ab.write_markdown("texture.md", lines)


if __name__ == "__main__":
    main()
