#!/usr/bin/env python3
"""Splits a LAS/LAZ scan into many small LAZ files, the layout an octree writer
(Potree 1.x, Entwine) leaves: the points of each cell of a regular grid go to
one file whose header carries the bounds of its cell, not of its points, and
whose offset is the cell's minimum. Used by the out-of-core test (multi-file
memory budget) and bench/build_bench.py.

Usage: split_laz.py INPUT OUT_DIR [--cells 16x16x8] [--tiles 1x1] [--min-files 1000]
Prints the number of files and points written as JSON.
"""
import argparse
import json
import os
import sys

import laspy
import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input")
    ap.add_argument("out_dir")
    ap.add_argument("--cells", default="16x16x8", help="grid cells per axis over the (tiled) bounds")
    ap.add_argument("--tiles", default="1x1", help="copies of the input side by side in x/y, 10%% apart")
    ap.add_argument("--min-files", type=int, default=1000, help="fail unless at least this many files result")
    args = ap.parse_args()
    cx, cy, cz = (int(v) for v in args.cells.split("x"))
    tx, ty = (int(v) for v in args.tiles.split("x"))

    src = laspy.read(args.input)
    x0, y0, z0 = np.asarray(src.x), np.asarray(src.y), np.asarray(src.z)
    dx, dy = (x0.max() - x0.min()) * 1.1, (y0.max() - y0.min()) * 1.1
    x = np.concatenate([x0 + i * dx for i in range(tx) for _ in range(ty)])
    y = np.concatenate([y0 + j * dy for _ in range(tx) for j in range(ty)])
    z = np.tile(z0, tx * ty)
    idx = np.tile(np.arange(len(x0)), tx * ty)
    lo = np.array([x.min(), y.min(), z.min()])
    hi = np.array([x.max(), y.max(), z.max()])
    size = (hi - lo) / np.array([cx, cy, cz]) * (1 + 1e-9)
    cell = np.floor((np.stack([x, y, z], axis=1) - lo) / size).astype(np.int64)
    cell = np.minimum(cell, [cx - 1, cy - 1, cz - 1])
    key = (cell[:, 0] * cy + cell[:, 1]) * cz + cell[:, 2]
    order = np.argsort(key, kind="stable")
    keys, starts = np.unique(key[order], return_index=True)
    if len(keys) < args.min_files:
        sys.exit(f"split_laz: only {len(keys)} non-empty cells (need {args.min_files}); use more --cells")
    os.makedirs(args.out_dir, exist_ok=True)
    ends = list(starts[1:]) + [len(order)]
    fmt = src.header.point_format.id
    for k, s, e in zip(keys, starts, ends):
        sel = order[s:e]
        c = np.array([k // (cy * cz), (k // cz) % cy, k % cz])
        cmin, cmax = lo + c * size, lo + (c + 1) * size
        header = laspy.LasHeader(point_format=fmt, version=src.header.version)
        header.scales = src.header.scales
        header.offsets = cmin  # per-file offsets, as an octree writer sets them
        # The source's coordinate system (its WKT and GeoTIFF VLRs), as such a writer keeps it.
        header.vlrs.extend(v for v in src.header.vlrs if v.user_id == "LASF_Projection")
        rec = laspy.ScaleAwarePointRecord.zeros(len(sel), header=header)
        rec.x, rec.y, rec.z = x[sel], y[sel], z[sel]
        for name in src.point_format.standard_dimension_names:  # extra bytes are left out
            if name not in ("X", "Y", "Z"):
                rec[name] = src[name][idx[sel]]
        path = os.path.join(args.out_dir, f"r{int(k):06d}.laz")
        with laspy.open(path, mode="w", header=header) as w:
            w.write_points(rec)
        # The header's bounds are the cell's, not the points' (Potree 1.x).
        with open(path, "r+b") as f:
            f.seek(179)
            f.write(np.array([cmax[0], cmin[0], cmax[1], cmin[1], cmax[2], cmin[2]], "<f8").tobytes())
    print(json.dumps({"files": int(len(keys)), "points": int(len(x))}))


if __name__ == "__main__":
    main()
