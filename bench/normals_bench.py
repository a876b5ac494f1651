#!/usr/bin/env python3
"""Normal estimation on a chart: each estimator's angular error against true
normals and its lit FLIP, against the build of build_bench's 10 M-point LAS.

Estimators: PCA of the k nearest input points (`--normal-k K`, exact grid
search; docs/ARCHITECTURE.md, "Normals") for K in 6, 8, 10, 12, 16 (16: the
default).

Surfaces with true normals, built from positions alone (normals estimated as
for a scan):
- analytic, sampled with jitter at spacing s: a plane, the plane with noise
  of s/4 along its normal, a sphere of radius 20 s and a cylinder of radius
  3 s (the small radius a few neighbours already curve around);
- the scanned meshes (bunny, horse, igea, the dragon), sampled by
  surfcast-build (each surfel carries the mesh's own normal, the truth: the
  face's, or the dragon's OBJ vertex normals interpolated), their positions
  written again without normals.

Each set's leaves are exported (surfcast-export --format ply --level leaves)
and matched to the truth by position; the error is the unsigned angle (an
orientation flip is the orientation rule's, not the estimator's). Rendered,
Lambert-shaded, grey, ewa-pixel: the noisy plane and the sphere against the
same points drawn with their true normals (the normals' error alone), and
the meshes' vertices (--vertices-only) against the mesh rasterized with the
same light (accuracy_bench's "Model sweep on the scanned meshes"); FLIP per
k. Time: `surfcast-build --threads 2 --normal-k K` on the LAS, twice each:
the normals step and the level's queries (neighbours + h + weights) in
thread-seconds, and the build's seconds. Prints markdown tables for
bench/BENCHMARKS.md ("Normals on a chart") and writes
bench/report/normals_chart.png (accuracy against the build's seconds).

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/normals_bench.py [--ks 6,8,10,12,16] [--no-las]
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import accuracy_bench as ab  # noqa: E402
import build_bench  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")
DATA = os.path.join(ROOT, "..", "shared", "data")
REPORT = os.path.join(ROOT, "bench", "report")
MESHES = ["bunny.ply", "horse.ply", "igea.ply", "fg_spkMgDragon/fg_spkMgDragon.obj"]
S = 0.01  # analytic sampling step, metres


def run(cmd):
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stdout}{r.stderr}")
    return r.stdout


def write_ply(path, points, normals=None):
    """Positions, grey, and `normals` (None: zero, which the build estimates)."""
    ab.write_ply(path, points, np.zeros_like(points) if normals is None else normals, np.full_like(points, 0.8))


def leaves(tileset, work):
    """The set's leaf surfels as world positions and normals (the export's frame undone;
    surfcast-export writes each surfel as a flat Gaussian, its normal in its rotation)."""
    ply = os.path.join(work, "leaves.ply")
    run([os.path.join(BIN, "surfcast-export"), tileset, "--format", "ply", "--level", "leaves", "-o", ply])
    with open(ply, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode()
    names = re.findall(r"property float (\w+)", head)
    n = int(re.search(r"element vertex (\d+)", head).group(1))
    rec = np.frombuffer(data, dtype=[(k, "<f4") for k in names], count=n, offset=end)
    # "set x, y, z = A + x, B + z, C - y": world x = A + x, y = B + z, z = C - y.
    a, b, c = (float(v) for v in re.search(r"= (\S+) \+ x, (\S+) \+ z, (\S+) - y", head).groups())
    pos = np.column_stack([a + rec["x"].astype(np.float64), b + rec["z"], c - rec["y"].astype(np.float64)])
    # A flat Gaussian's normal: its rotation (w, x, y, z) applied to its thinnest axis, z (scale_2).
    w, qx, qy, qz = (rec[f"rot_{i}"].astype(np.float64) for i in range(4))
    norm = np.sqrt(w * w + qx * qx + qy * qy + qz * qz)
    w, qx, qy, qz = w / norm, qx / norm, qy / norm, qz / norm
    n = np.column_stack([2 * (qx * qz + w * qy), 2 * (qy * qz - w * qx), 1 - 2 * (qx * qx + qy * qy)])
    return pos, np.column_stack([n[:, 0], n[:, 2], -n[:, 1]])


def analytic(rng):
    """name -> (points, true normals)."""
    out = {}
    g = np.arange(0, 2.0, S)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    jitter = lambda n: rng.uniform(-0.25 * S, 0.25 * S, n)  # noqa: E731
    p = np.column_stack([x + jitter(x.size), y + jitter(x.size), np.zeros(x.size)])
    n = np.tile([0.0, 0.0, 1.0], (x.size, 1))
    out["plane"] = (p, n)
    q = p.copy()
    q[:, 2] = rng.normal(0, 0.25 * S, x.size)
    out["plane, noise s/4"] = (q, n)
    r = 20 * S  # the sphere: Fibonacci lattice at spacing about s
    m = int(4 * np.pi * r * r / (S * S))
    i = np.arange(m) + 0.5
    phi, theta = np.arccos(1 - 2 * i / m), np.pi * (1 + 5**0.5) * i
    d = np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])
    out["sphere r = 20 s"] = (r * d, d)
    r = 3 * S  # the cylinder: rings s apart, about s between points along each
    k = int(round(2 * np.pi * r / S))
    a, h = np.meshgrid(np.arange(k) * 2 * np.pi / k, np.arange(0, 1.0, S))
    a = a.ravel() + rng.uniform(0, 2 * np.pi / k, a.size) * 0.25
    d = np.column_stack([np.cos(a), np.sin(a), np.zeros(a.size)])
    out["cylinder r = 3 s"] = (np.column_stack([r * d[:, 0], r * d[:, 1], h.ravel()]), d)
    return out


def errors(truth_p, truth_n, est_p, est_n):
    """Unsigned angles (degrees) at the estimated points, against the nearest true point's normal."""
    dist, idx = cKDTree(truth_p).query(est_p)
    cos = np.abs(np.sum(truth_n[idx] * est_n, axis=1)) / (np.linalg.norm(truth_n[idx], axis=1) * np.linalg.norm(est_n, axis=1))
    return np.degrees(np.arccos(np.clip(cos, 0, 1))), dist.max()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ks", default="6,8,10,12,16")
    ap.add_argument("--no-las", action="store_true", help="leave out the timing on the 10 M-point LAS")
    args = ap.parse_args()
    ks = [int(k) for k in args.ks.split(",")]
    build = os.path.join(BIN, "surfcast-build")
    rows = {}  # (scene, k) -> (median, p95, rms)
    with tempfile.TemporaryDirectory() as work:
        scenes = analytic(np.random.default_rng(1))
        for mesh in MESHES:
            # The mesh sampled by the build: its surfels carry the faces' normals.
            run([build, "-q", os.path.join(DATA, mesh), "-o", os.path.join(work, "mesh")])
            scenes[os.path.basename(mesh).split(".")[0]] = leaves(os.path.join(work, "mesh"), work)
        for name, (p, n) in scenes.items():
            ply = os.path.join(work, "points.ply")
            write_ply(ply, p)
            for k in ks:
                out = os.path.join(work, "set")
                run([build, "-q", ply, "--normal-k", str(k), "-o", out])
                ep, en = leaves(out, work)
                angle, far = errors(p, n, ep, en)
                rows[name, k] = (np.median(angle), np.percentile(angle, 95), np.sqrt(np.mean(angle**2)), len(ep))
                print(f"{name} k={k}: median {rows[name, k][0]:.2f}°, p95 {rows[name, k][1]:.2f}°, "
                      f"{len(ep)} points (farthest match {far:.2g})", file=sys.stderr, flush=True)
        flips = {}  # (scene, k) -> FLIP, lit
        for name in ("plane, noise s/4", "sphere r = 20 s"):
            # Against the same points drawn with their true normals: the normals' error alone.
            p, n = scenes[name]
            ply = os.path.join(work, "points.ply")
            write_ply(ply, p, n)
            run([build, "-q", ply, "-o", os.path.join(work, "true")])
            ref, _, _ = ab.render(os.path.join(work, "true"), "ewa-pixel", None, "480x360", 1, os.path.join(work, "t.png"),
                                  shading="lambert", colour="0.8,0.8,0.8")
            write_ply(ply, p)
            for k in ks:
                out = os.path.join(work, "lit")
                run([build, "-q", ply, "--normal-k", str(k), "-o", out])
                img, _, _ = ab.render(out, "ewa-pixel", None, "480x360", 1, os.path.join(work, "lit.png"),
                                      shading="lambert", colour="0.8,0.8,0.8")
                flips[name, k] = ab.metrics(ref, img)[2]
                print(f"{name} lit k={k}: FLIP {flips[name, k]:.4f}", file=sys.stderr, flush=True)
        for mesh in ("bunny", "horse", "igea"):
            src, _, camera, ref = ab.mesh_view(mesh, "480x360", work, "lambert")
            for k in ks:
                out = os.path.join(work, "lit")
                run([build, "-q", "--vertices-only", src, "--normal-k", str(k), "-o", out])
                img, _, _ = ab.render(out, "ewa-pixel", camera, "480x360", 1, os.path.join(work, "lit.png"),
                                      shading="lambert", colour="0.8,0.8,0.8")
                flips[mesh, k] = ab.metrics(ref, img)[2]
                print(f"{mesh} lit k={k}: FLIP {flips[mesh, k]:.4f}", file=sys.stderr, flush=True)
        seconds, others = {}, {}  # k -> normals thread-s; k -> (neighbours + h thread-s, build s), of the same run
        if not args.no_las:
            las = os.path.join(work, "lion_tiled.las")
            total = build_bench.tiled_las(os.path.join(DATA, "lion_takanawa.copc.laz"), 6, 5, las)
            for k in ks:  # twice each, the faster kept
                for _ in range(2):
                    stdout = run([build, las, "--threads", "2", "--normal-k", str(k), "-o", os.path.join(work, "las")])
                    t = float(re.search(r"normals ([0-9.]+)", stdout).group(1))
                    # Below k = 9 no point records its d_8 (--spacing-k): isolation queries its level instead.
                    h = float(re.search(r"neighbours\+h\+weights ([0-9.]+)", stdout).group(1))
                    wall = float(re.search(r"total ([0-9.]+) s", stdout).group(1))
                    if k not in seconds or t < seconds[k]:
                        seconds[k], others[k] = t, (h, wall)
                    print(f"LAS k={k}: normals {t:.2f}, neighbours+h {h:.2f} thread-s, build {wall:.1f} s", file=sys.stderr, flush=True)
    names = list(scenes)
    print("Median / 95th-percentile angle to the true normal, degrees:\n")
    print("| k | " + " | ".join(names) + " |")
    print("|---:|" + "---:|" * len(names))
    for k in ks:
        print(f"| {k} | " + " | ".join(f"{rows[s, k][0]:.2f} / {rows[s, k][1]:.2f}" for s in names) + " |")
    if seconds:
        print("\nThe 10 M-point LAS, --threads 2 (the faster of two builds):\n")
        print("| k | normals thread-s | neighbours + h + weights thread-s | build s |")
        print("|---:|---:|---:|---:|")
        for k in ks:
            print(f"| {k} | {seconds[k]:.2f} | {others[k][0]:.2f} | {others[k][1]:.1f} |")
    meshes = list(dict.fromkeys(m for m, _ in flips))
    print("\nFLIP, Lambert-shaded (meshes: against the mesh; plane and sphere: against their points drawn with true normals):\n")
    print("| k | " + " | ".join(meshes) + " |")
    print("|---:|" + "---:|" * len(meshes))
    for k in ks:
        print(f"| {k} | " + " | ".join(f"{flips[m, k]:.4f}" for m in meshes) + " |")
    chart(names, ks, rows, flips, {k: others[k][1] for k in others})


def chart(names, ks, rows, flips, builds):
    """Median angle and lit FLIP per scene against the LAS build's seconds (or k without them)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    x = [builds[k] for k in ks] if builds else ks
    for i, name in enumerate(names):
        if any(rows[name, k][0] > 0.005 for k in ks):  # the clean plane's 0 has no place on a log scale
            axes[0].plot(x, [rows[name, k][0] for k in ks], marker="o", ls="none", color=f"C{i}", label=name)
        if (name, ks[0]) in flips:
            axes[1].plot(x, [flips[name, k] for k in ks], marker="o", ls="none", color=f"C{i}", label=name)
    for ax in axes:
        for j, (k, xv) in enumerate(zip(ks, x)):  # labels staggered: close times do not overlap
            ax.axvline(xv, color="0.85", lw=0.8, zorder=0)
            ax.text(xv, 1.0 + 0.04 * (j % 2), f"k={k}", transform=ax.get_xaxis_transform(), fontsize=7, ha="center", va="bottom")
        ax.set_xlabel("build of the 10 M-point LAS, seconds (--threads 2)" if builds else "k")
        ax.set_yscale("log")
        ax.legend(fontsize=7)
    axes[0].set_ylabel("median angle to the true normal (degrees)")
    axes[1].set_ylabel("FLIP, Lambert-shaded, ewa-pixel")
    fig.suptitle("PCA normals of k neighbours: accuracy against build time")
    fig.tight_layout()
    os.makedirs(REPORT, exist_ok=True)
    fig.savefig(os.path.join(REPORT, "normals_chart.png"), dpi=110)


if __name__ == "__main__":
    main()
