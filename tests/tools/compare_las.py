#!/usr/bin/env python3
"""Compares an exported LAS/LAZ file with the LAS file a set was built from,
read by laspy (an independent reader), for tests/export_test.cpp.

Usage: compare_las.py ORIGINAL EXPORTED [--box X0,Y0,Z0,X1,Y1,Z1] [--classes 2,6] [--tolerance T]

Each exported point is matched to the nearest unmatched original point
within T on every axis (T under the original's scale), among the original
points the filter keeps with the box grown by T.
Prints one JSON object: the exported count, the counts the filter keeps
with the box shrunk and grown by T, how many exported points matched, the
largest position error, the exported classes, the largest GPS time and
scan angle errors,
and for each other attribute how many matched points carry the original's
value (colour as the original stores it: the export gives back 8-bit values
written in LAS's 16-bit fields as they were).
"""
import argparse
import json

import laspy
import numpy as np


def main():
    p = argparse.ArgumentParser()
    p.add_argument("original")
    p.add_argument("exported")
    p.add_argument("--box")
    p.add_argument("--classes")
    p.add_argument("--tolerance", type=float, default=0.0)
    a = p.parse_args()
    o, e = laspy.read(a.original), laspy.read(a.exported)
    oxyz = np.column_stack([o.x, o.y, o.z])
    exyz = np.column_stack([e.x, e.y, e.z]) if len(e.points) else np.zeros((0, 3))

    def kept(grow):
        m = np.ones(len(o.points), dtype=bool)
        if a.box:
            b = [float(v) for v in a.box.split(",")]
            for axis in range(3):
                m &= (oxyz[:, axis] >= b[axis] - grow) & (oxyz[:, axis] <= b[3 + axis] + grow)
        if a.classes:
            m &= np.isin(np.asarray(o.classification), [int(c) for c in a.classes.split(",")])
        return m

    # Original points by their cell of the original's scale; an exported point
    # looks in its own cell and the 26 around it for one within the tolerance.
    scale = np.asarray(o.header.scales)
    candidates = np.nonzero(kept(a.tolerance))[0]
    index = {}
    for i, k in zip(candidates, np.round(oxyz[candidates] / scale).astype(np.int64)):
        index.setdefault(tuple(k), []).append(i)
    # The nearest unmatched one within T; the 27 cells hold every candidate
    # while T is under one cell.
    assert np.all(a.tolerance < scale), "the tolerance must be under the original's scale"
    offsets = [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]
    taken = set()
    match = []
    for p, k in zip(exyz, np.round(exyz / scale).astype(np.int64)):
        found, best = -1, np.inf
        for d in offsets:
            for i in index.get((k[0] + d[0], k[1] + d[1], k[2] + d[2]), []):
                dist = np.max(np.abs(oxyz[i] - p))
                if i not in taken and dist <= a.tolerance and dist < best:
                    found, best = i, dist
        if found >= 0:
            taken.add(found)
        match.append(found)
    matched = np.array([m for m in match if m >= 0], dtype=np.int64)
    found = np.array([j for j, m in enumerate(match) if m >= 0], dtype=np.int64)
    result = {
        "exported": int(len(e.points)),
        "kept_shrunk": int(kept(-a.tolerance).sum()),
        "kept_grown": int(kept(a.tolerance).sum()),
        "matched": int(len(matched)),
        "largest_error": float(np.abs(exyz[found] - oxyz[matched]).max()) if len(found) else 0.0,
        "classes": sorted(int(c) for c in np.unique(np.asarray(e.classification))),
        "point_format": int(e.header.point_format.id),
        # every point inside the header's bounds (both from the same scaled integers)
        "inside_header": bool(len(exyz) == 0 or (np.all(exyz >= np.asarray(e.header.mins) - 1e-9) and
                                                 np.all(exyz <= np.asarray(e.header.maxs) + 1e-9))),
        "header_slack": float(max(np.max(exyz.min(axis=0) - np.asarray(e.header.mins)),
                                  np.max(np.asarray(e.header.maxs) - exyz.max(axis=0)))) if len(exyz) else 0.0,
        "same": {},
    }
    dims = set(o.point_format.dimension_names)
    def degrees(points, index):  # whole degrees (formats 0-5) or 0.006-degree units (6-10)
        if "scan_angle_rank" in points.point_format.dimension_names:
            return np.asarray(points.scan_angle_rank)[index].astype(np.float64)
        return np.asarray(points.scan_angle)[index] * 0.006
    if len(found):
        result["scan_angle_error"] = float(np.abs(degrees(o, matched) - degrees(e, found)).max())
    for d in ["intensity", "classification", "return_number", "number_of_returns", "user_data", "gps_time", "red", "green", "blue"]:
        if d not in dims or not len(found):
            continue
        ov = np.asarray(getattr(o, d))[matched].astype(np.float64)
        ev = np.asarray(getattr(e, d))[found].astype(np.float64)
        if d == "gps_time":  # a float the set quantizes: its largest error instead
            result["gps_time_error"] = float(np.abs(ov - ev).max())
        else:
            result["same"][d] = int(np.sum(ov == ev))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
