#!/usr/bin/env python3
"""Edge antialiasing (Zwicker et al. 2001, §7): --edge-aa off against on at
several tau, on silhouettes against exact references, and on interiors where
it must change nothing.

Silhouettes:
- the accuracy harness's open disc (a band-limited checkerboard, surfels on
  a jittered grid at 0.5 units), against its 16 x 16 ray-cast reference;
- the shared bunny, horse and igea meshes (vertices as surfels, grey,
  Lambert), against the mesh rasterized at 4 x 4 samples per pixel
  (surfcast-mesh-reference).
FLIP and PSNR over the whole image and over the silhouette pixels alone:
those within one pixel of the reference's boundary between surface and
background.

Interiors: the built-in scanned scene (default view) and the accuracy
harness's 10x density jump, drawn on magenta with edge antialiasing off and
on: pixels whose 3 x 3 neighbourhood is covered without it are interior, and
any change there is darkening where sampling is merely sparse.

Writes bench/report/edge_aa.csv and edge_aa.md (and prints the Markdown).

Usage: bench/.venv/bin/python bench/edge_aa_bench.py [--size 320x240]
"""
import argparse
import os
import sys
import tempfile

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import accuracy_bench as ab  # noqa: E402

TAUS = [0.75, 1.5, 3.0, 4.0, 6.0, 8.0]


def view(tileset, camera, size, png, aa, tau=None, background="1,1,1", shading="unlit", colour=None):
    """ewa-pixel with --edge-aa on or off."""
    options = ["--edge-aa", "on" if aa else "off", *(["--edge-tau", str(tau)] if tau is not None else [])]
    return ab.render(tileset, "ewa-pixel", camera, size, 1, png, shading=shading, colour=colour, background=background,
                     options=options)[0]


def boundary(covered):
    """Pixels within one pixel of the edge of `covered`."""
    p = np.pad(covered, 1, mode="edge")
    h, w = covered.shape
    shifts = [p[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
    return np.any(shifts, axis=0) & ~np.all(shifts, axis=0)


def scores(ref, img, edge):
    import flip_evaluator as flip
    error_map, mean_flip, _ = flip.evaluate(ref.astype(np.float32), img.astype(np.float32), "LDR")
    mse_edge = float(((ref - img) ** 2)[edge].mean())
    return {"flip": float(mean_flip), "flip_edge": float(error_map[edge].mean()),
            "psnr": ab.peak_signal_noise_ratio(ref, img, data_range=1.0), "psnr_edge": 10 * np.log10(1 / max(mse_edge, 1e-12))}


def silhouettes(size, tmp):
    rows = []
    width, height = (int(v) for v in size.split("x"))
    surfaces, camera = ab.scenes()["open-boundary"]
    ref = ab.reference(surfaces, camera, width, height)
    edge = boundary(np.any(np.abs(ref - ab.BACKGROUND) > 1e-3, axis=2))
    rng = np.random.default_rng(1)
    pts, nrm, col = (np.concatenate(x) for x in zip(*(s.samples(rng) for s in surfaces)))
    ply = os.path.join(tmp, "disc.ply")
    ab.write_ply(ply, pts, nrm, col)
    tileset = os.path.join(tmp, "disc")
    ab.run([os.path.join(ab.BIN, "surfcast-build"), "-q", ply, "-o", tileset])
    cases = [("open-boundary", tileset, camera, ref, edge, {})]
    for mesh in ab.MESHES:
        _, mesh_set, mesh_camera, mesh_ref = ab.mesh_view(mesh, size, tmp)
        mesh_edge = boundary(np.any(np.abs(mesh_ref - 1.0) > 1e-3, axis=2))
        cases.append(("mesh-" + mesh, mesh_set, mesh_camera, mesh_ref, mesh_edge,
                      {"shading": "lambert", "colour": "0.8,0.8,0.8"}))
    for name, tileset, camera, ref, edge, extra in cases:
        for aa, tau in [(False, None)] + [(True, t) for t in TAUS]:
            img = view(tileset, camera, size, os.path.join(tmp, "f.png"), aa, tau, **extra)
            s = scores(ref, img, edge)
            rows.append({"scene": name, "edge_aa": "on" if aa else "off", "tau": tau or "", **s, "edge_pixels": int(edge.sum())})
            print(f"{name} aa={aa} tau={tau}: {s}", file=sys.stderr)
    return rows


def interiors(size, tmp):
    rows = []
    scene = os.path.join(tmp, "scene")
    ab.run([os.path.join(ab.BIN, "surfcast-build"), "-q", "--default-scene", "-o", scene])
    # The 10x density jump of the accuracy harness (radius_synthetic_study).
    left = ab.Patch([-8, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-8, 8, -20, 20), spacing=0.5,
                    texture=lambda a, b: np.full((len(a), 3), 0.6))
    right = ab.Patch([8, 0, 0], [1, 0, 0], [0, 1, 0], extent=(-8, 8, -20, 20), spacing=0.05,
                     texture=lambda a, b: np.full((len(a), 3), 0.6))
    rng = np.random.default_rng(2)
    pts, nrm, col = (np.concatenate(x) for x in zip(*(p.samples(rng) for p in (left, right))))
    ply = os.path.join(tmp, "jump.ply")
    ab.write_ply(ply, pts, nrm, col)
    jump = os.path.join(tmp, "jump")
    ab.run([os.path.join(ab.BIN, "surfcast-build"), "-q", ply, "-o", jump])
    for name, tileset, camera in [("built-in scene", scene, None), ("density jump 10x", jump, "0,-22,14,0,2,0,0,0,1,50"),
                                  ("density jump 10x, magnified", jump, "-0.5,-3,2.5,-0.5,0,0,0,0,1,50")]:
        off = view(tileset, camera, size, os.path.join(tmp, "i.png"), False, background="1,0,1")
        covered = np.any(np.abs(off - np.array([1.0, 0.0, 1.0])) > 1e-3, axis=2)
        p = np.pad(covered, 1)
        h, w = covered.shape
        interior = np.all([p[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
        for tau in TAUS:
            on = view(tileset, camera, size, os.path.join(tmp, "i.png"), True, tau, background="1,0,1")
            diff = np.abs(on - off).max(axis=2)[interior]
            rows.append({"scene": name, "tau": tau, "interior_pixels": int(interior.sum()),
                         "changed": int((diff > 1.5 / 255).sum()), "mean_change": float(diff.mean())})
            print(f"{name} tau={tau}: {rows[-1]}", file=sys.stderr)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x240")
    args = ap.parse_args()
    os.makedirs(ab.REPORT, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        sil = silhouettes(args.size, tmp)
        inner = interiors(args.size, tmp)
    ab.write_csv("edge_aa.csv", sil)
    ab.write_csv("edge_aa_interiors.csv", inner)
    lines = ["| scene | edge AA | tau | FLIP | FLIP, silhouette pixels | PSNR dB | PSNR, silhouette |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for r in sil:
        lines.append(f"| {r['scene']} | {r['edge_aa']} | {r['tau']} | {r['flip']:.4f} | {r['flip_edge']:.4f} | "
                     f"{r['psnr']:.2f} | {r['psnr_edge']:.2f} |")
    lines += ["", "| interior of | tau | interior pixels | changed by edge AA (> 1.5/255) | mean change |",
              "|---|---:|---:|---:|---:|"]
    for r in inner:
        lines.append(f"| {r['scene']} | {r['tau']} | {r['interior_pixels']} | {r['changed']} | {r['mean_change']:.5f} |")
    ab.write_markdown("edge_aa.md", lines)


if __name__ == "__main__":
    main()
