#!/usr/bin/env python3
"""Reads a COPC file with laspy's CopcReader (an independent reader of the
format: it needs the info VLR first, the hierarchy EVLR and a chunk per node)
and compares it with a LAZ file of the same points, for tests/export_test.cpp.

Usage: check_copc.py COPC LAZ

Prints one JSON object: the points a whole query returns, those of each
level, the points of the LAZ file, whether both hold the same records
(sorted by position), for a query of the half of the bounds below the
middle x the points it returns against those of the whole query there, how
many cells of the root's grid the LAZ file's points occupy, and what
laspy.read finds reading the COPC file as plain LAZ.
"""
import json
import sys

import laspy
import numpy as np


def records(points):
    cols = [np.asarray(points.X), np.asarray(points.Y), np.asarray(points.Z), np.asarray(points.intensity),
            np.asarray(points.classification), np.asarray(points.return_number), np.asarray(points.gps_time)]
    a = np.column_stack([c.astype(np.float64) for c in cols])
    return a[np.lexsort(a.T[::-1])]


def main():
    copc_path, laz_path = sys.argv[1:3]
    laz = laspy.read(laz_path)
    result = {"laz": int(len(laz.points))}
    with laspy.CopcReader.open(copc_path) as r:
        everything = r.query()
        result["query"] = int(len(everything))
        result["levels"] = []
        for level in range(0, 21):
            n = len(r.query(level=level))
            if n == 0 and level > 0 and sum(result["levels"]) == result["query"]:
                break
            result["levels"].append(int(n))
        result["same_records"] = bool(len(everything) == len(laz.points) and np.array_equal(records(everything), records(laz.points)))
        mins, maxs = r.header.mins, r.header.maxs
        # A quarter of the scale past a record's grid: no point lies on it,
        # whichever way a reader rounds the bound.
        scale, offset = r.header.scales[0], r.header.offsets[0]
        mid = offset + (np.floor(((mins[0] + maxs[0]) / 2 - offset) / scale) + 0.25) * scale
        half = r.query(bounds=laspy.copc.Bounds(mins=np.array([mins[0], mins[1]]), maxs=np.array([mid, maxs[1]])))
        result["half_query"] = int(len(half))
        result["half_expected"] = int(np.sum(np.asarray(everything.x) <= mid))
        result["spacing"] = float(r.copc_info.spacing)
    # Read as plain LAZ (the chunk table and its offset, which CopcReader does not use).
    plain = laspy.read(copc_path)
    result["plain"] = int(len(plain.points))
    result["plain_same_records"] = bool(len(plain.points) == len(laz.points) and
                                        np.array_equal(records(plain.points), records(laz.points)))
    with laspy.CopcReader.open(copc_path) as r:
        # The cells of the root's grid (spacing wide, from the cube's corner)
        # that the LAZ file's points occupy: the root holds one point in each.
        corner = np.asarray(r.copc_info.center) - r.copc_info.halfsize
        xyz = np.column_stack([laz.x, laz.y, laz.z])
        cells = np.clip(np.floor((xyz - corner) / r.copc_info.spacing), 0, 127).astype(np.int64)
        result["root_cells"] = int(len(np.unique(cells[:, 0] * 128 * 128 + cells[:, 1] * 128 + cells[:, 2])))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
