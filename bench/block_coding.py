#!/usr/bin/env python3
"""Block coding: one kd-tree of every attribute (--codec draco) against the
positions in a kd-tree and the other attributes column by column
(draco-columns, the default), on the shared scans, normals at the same
angular error in both.

For each scan, a default build and one with --attributes all, in each codec
(built one after another, alternating, on one thread): the set's bytes
(hierarchy.bin + blocks.bin) per input point and against the input's LAZ
(a LAS input compressed by laspy's lazrs), the build's encode step in
thread-seconds (its summary's "encode"), and decoding every block as a client
does (surfcast-decode-bench, the fastest of three passes). Prints markdown
tables for bench/BENCHMARKS.md ("Block coding").

Usage: bench/block_coding.py [--build build] [--data ../shared/data] [SCAN ...]
Needs the test venv (laspy): build/test-venv/bin/python bench/block_coding.py
"""
import json
import os
import re
import subprocess
import tempfile

import set_bytes

SCANS = ["Megaplot.laz", "lone-star.laz", "lion_takanawa.copc.laz", "autzen_trim.las", "CSite1_red1-utm.pcd", "bunny.ply"]
# Each codec with normals at the same angular error (RMS 0.18°): 8 bits per
# component in one kd-tree (the default before draco-columns), 9 per
# octahedral coordinate in the columns (the default now).
CODECS = {"draco": ["--codec", "draco", "--normal-bits", "8"], "draco-columns": ["--codec", "draco-columns", "--normal-bits", "9"]}


def build(binary, scan, args, out):
    size, info, stdout = set_bytes.build(binary, scan, ["--threads", "1", *args], out)
    return size, float(re.search(r"encode ([0-9.]+)", stdout).group(1)), info


def decode_ns(tool, folder):
    run = subprocess.run([tool, folder], check=True, capture_output=True, text=True)
    return json.loads(run.stdout)["ns_per_surfel"]


def main():
    a = set_bytes.arguments(__doc__, SCANS)
    binary = a.binary
    tool = os.path.join(a.build, "bin", "surfcast-decode-bench")
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for name in a.scans:
            scan = os.path.join(a.data, name)
            laz_bytes = set_bytes.laz_bytes(scan, work) if name.endswith((".las", ".laz")) else None
            for label, args in [("default", []), ("--attributes all", ["--attributes", "all"])]:
                if label != "default" and laz_bytes is None:
                    continue
                got = {}
                for codec, codec_args in CODECS.items():
                    out = os.path.join(work, codec)
                    size, encode, info = build(binary, scan, [*args, *codec_args], out)
                    got[codec] = (size, encode, decode_ns(tool, out), info["input_points"], info["surfels"])
                rows.append((name, label, laz_bytes, got))
    print("| scan | build | points | surfels | draco B/pt | draco-columns B/pt | change | × LAZ (draco → columns) "
          "| encode s (draco → columns) | decode ns/surfel (draco → columns) |")
    print("|---|---|---:|---:|---:|---:|---:|---|---|---|")
    for name, label, laz_bytes, got in rows:
        old, new = got["draco"], got["draco-columns"]
        points = old[3]
        laz = f"{old[0] / laz_bytes:.2f} → {new[0] / laz_bytes:.2f}" if laz_bytes else "(not LAS)"
        print(f"| `{name}` | {label} | {points:,} | {old[4]:,} | {old[0] / points:.2f} | {new[0] / points:.2f} | "
              f"{100 * (new[0] / old[0] - 1):+.0f} % | {laz} | {old[1]:.2f} → {new[1]:.2f} | {old[2]:.0f} → {new[2]:.0f} |")


if __name__ == "__main__":
    main()
