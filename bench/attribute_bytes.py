#!/usr/bin/env python3
"""What each kept dimension costs a set, against the input's own LAZ bytes.

For each LAS/LAZ scan: its LAZ bytes (a LAS file compressed by laspy's
lazrs, the `laz` crate that LASzip-compatible writers share), the set's bytes
(hierarchy.bin + blocks.bin) of a default build and of --attributes all, and
per dimension the bytes per input point it adds to a build that keeps the four
LiDAR attributes exactly (--attributes intensity,classification,
return_number,number_of_returns): built once with the dimension and once
without. Prints markdown tables for bench/BENCHMARKS.md ("Attribute bytes").

Usage: bench/attribute_bytes.py [--build build] [--data ../shared/data] [SCAN ...]
Needs the test venv (laspy): build/test-venv/bin/python bench/attribute_bytes.py
"""
import os
import tempfile

import laspy

import set_bytes

SCANS = ["Megaplot.laz", "lone-star.laz", "lion_takanawa.copc.laz", "autzen_trim.las"]
LIDAR = ["intensity", "classification", "return_number", "number_of_returns"]


def build(binary, scan, args, out):
    size, info, _ = set_bytes.build(binary, scan, ["-q", *args], out)
    return size, info


def main():
    a = set_bytes.arguments(__doc__, SCANS)
    binary = a.binary
    totals, costs = [], {}
    with tempfile.TemporaryDirectory() as work:
        for name in a.scans:
            scan = os.path.join(a.data, name)
            laz_bytes = set_bytes.laz_bytes(scan, work)
            points = laspy.open(scan).header.point_count
            default, _ = build(binary, scan, [], os.path.join(work, "default"))
            everything, info = build(binary, scan, ["--attributes", "all"], os.path.join(work, "all"))
            totals.append((name, points, laz_bytes, default, everything))
            # The dimensions --attributes all stores, less the four kept below and the low parts.
            stored = [x["name"] for x in info["attributes"] if x.get("kind") and x["name"] not in LIDAR and not x["name"].endswith(":low")]
            base, _ = build(binary, scan, ["--attributes", ",".join(LIDAR)], os.path.join(work, "base"))
            costs[(name, "intensity, exact (against 12 bits)")] = (base - default) / points
            for dim in stored:
                with_dim, _ = build(binary, scan, ["--attributes", ",".join(LIDAR + [dim])], os.path.join(work, "dim"))
                costs[(name, dim)] = (with_dim - base) / points
    print("| scan | points | input LAZ bytes/point | default set | × LAZ | --attributes all | × LAZ |")
    print("|---|---|---|---|---|---|---|")
    for name, points, laz_bytes, default, everything in totals:
        print(f"| {name} | {points:,} | {laz_bytes / points:.2f} | {default / points:.2f} | {default / laz_bytes:.2f} | "
              f"{everything / points:.2f} | {everything / laz_bytes:.2f} |")
    print()
    print("| scan | dimension | bytes per input point |")
    print("|---|---|---|")
    for (name, dim), cost in costs.items():
        print(f"| {name} | {dim} | {cost:.2f} |")


if __name__ == "__main__":
    main()
