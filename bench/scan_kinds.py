#!/usr/bin/env python3
"""Set bytes against LAZ on kinds of scan the shared ones lack, made from them.

- 16-bit colour: lion_takanawa.copc.laz, whose colours are 8-bit values
  stored in 16 bits, given real low bits: each channel the mean of the
  point's 8 nearest neighbours' (itself included) 8-bit values times 257,
  rounded, so the low bits vary as a smooth colour field's would.
- Intensity only: autzen_trim.las without its colour (point format 1).

Each beside the scan it was made from: the LAS written by laspy, its LAZ
(laspy + lazrs), and the default build's bytes (hierarchy.bin + blocks.bin).
Prints a markdown table for bench/BENCHMARKS.md ("Block coding").

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/scan_kinds.py [--build build] [--data ../shared/data]
"""
import os
import tempfile

import laspy
import numpy as np
from scipy.spatial import cKDTree

import set_bytes


def main():
    a = set_bytes.arguments(__doc__)
    binary = a.binary
    with tempfile.TemporaryDirectory() as work:
        copc = laspy.read(os.path.join(a.data, "lion_takanawa.copc.laz"))
        # Its points as a plain LAS 1.4 (laspy writes no COPC), and again with 16-bit colour.
        header = laspy.LasHeader(point_format=copc.header.point_format, version="1.4")
        header.scales, header.offsets = copc.header.scales, copc.header.offsets
        lion, wide = laspy.LasData(header), laspy.LasData(header)
        lion.points = copc.points.copy()
        wide.points = copc.points.copy()
        xyz = np.column_stack([copc.x, copc.y, copc.z])
        _, near = cKDTree(xyz).query(xyz, k=8)
        for channel in ("red", "green", "blue"):
            c8 = np.asarray(getattr(copc, channel)) // 256
            setattr(wide, channel, np.round(c8[near].mean(axis=1) * 257).astype(np.uint16))
        autzen = laspy.read(os.path.join(a.data, "autzen_trim.las"))
        grey = laspy.convert(autzen, point_format_id=1)
        scans = [("lion_takanawa (8-bit colour in 16-bit fields)", lion), ("the same, 16-bit colour", wide),
                 ("autzen_trim (8-bit colour)", autzen), ("the same, intensity only", grey)]
        print("| scan | points | colour bits stored | LAZ B/pt | default set B/pt | × LAZ |")
        print("|---|---:|---:|---:|---:|---:|")
        for i, (name, data) in enumerate(scans):
            las = os.path.join(work, f"{i}.las")
            laz = os.path.join(work, f"{i}.laz")
            data.write(las)
            data.write(laz)
            n = len(data.points)
            size, info, _ = set_bytes.build(binary, las, ["-q", "--threads", "2"], os.path.join(work, f"set{i}"))
            bits = info["color_bits"]
            laz_bpp = os.path.getsize(laz) / n
            print(f"| {name} | {n:,} | {bits} | {laz_bpp:.2f} | {size / n:.2f} | {size / os.path.getsize(laz):.2f} |", flush=True)


if __name__ == "__main__":
    main()
