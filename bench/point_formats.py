#!/usr/bin/env python3
"""Set bytes against LAZ for every LAS point format, 0 to 10, each written
with its dimensions filled from a real scan.

The scan is autzen_trim.las (point format 3: intensity, returns, flags,
classification, scan angle, user data, point source, GPS time, colour). Each
format takes every dimension it shares with it; the ones autzen lacks are
filled from its own values, as a real scanner's would vary:
- scan angle (formats 6-10): the scan angle rank in 0.006° units;
- NIR (8, 10): the point's red channel;
- wave packets (4, 5, 9, 10): descriptor 1, packets of 256 bytes end to end in
  acquisition (GPS time) order, the return's location in its waveform from its
  return number (1000 ps apart) and the pulse's direction from the scan angle.
Scan channel and the overlap flag stay 0, as a one-channel scanner writes them.

Per format: the LAS written by laspy, its LAZ (laspy + lazrs) and the set's
bytes of a default build and of --attributes all. Prints a markdown table for
bench/BENCHMARKS.md ("Attribute bytes").

Usage: build/test-venv/bin/python bench/point_formats.py [--build build] [--data ../shared/data]
"""
import os
import tempfile

import laspy
import numpy as np

import set_bytes


def filled(scan, point_format):
    """The scan's points in `point_format`, every dimension filled (see above)."""
    header = laspy.LasHeader(point_format=point_format, version="1.4")
    header.scales, header.offsets = scan.header.scales, scan.header.offsets
    out = laspy.LasData(header)
    out.points = laspy.ScaleAwarePointRecord.zeros(len(scan.points), header=header)
    # By dimension name, packed bit fields (returns, flags, classification) included.
    names = set(header.point_format.dimension_names)
    for name in scan.point_format.dimension_names:
        if name in names and name not in ("X", "Y", "Z"):
            out[name] = np.asarray(scan[name])
    out.X, out.Y, out.Z = scan.X, scan.Y, scan.Z
    angle = np.asarray(scan.scan_angle_rank).astype(np.float64)
    if "scan_angle" in names:
        out.scan_angle = np.round(angle / 0.006).astype(np.int16)
    if "nir" in names:
        out.nir = np.asarray(scan.red)
    if "wavepacket_index" in names:
        out.wavepacket_index = np.ones(len(angle), dtype=np.uint8)
        out.wavepacket_size = np.full(len(angle), 256, dtype=np.uint32)
        order = np.argsort(np.asarray(scan.gps_time), kind="stable")
        offset = np.empty(len(order), dtype=np.uint64)
        offset[order] = 256 * np.arange(len(order), dtype=np.uint64)
        out.wavepacket_offset = offset
        out.return_point_wave_location = (1000.0 * np.asarray(scan.return_number)).astype(np.float32)
        theta = np.radians(angle)
        out.x_t = (np.sin(theta) * 1e-4).astype(np.float32)
        out.y_t = np.zeros(len(angle), dtype=np.float32)
        out.z_t = (-np.cos(theta) * 1e-4).astype(np.float32)
    return out


def main():
    a = set_bytes.arguments(__doc__)
    scan = laspy.read(os.path.join(a.data, "autzen_trim.las"))
    print("| point format | dimensions | LAZ B/pt | default set B/pt | × LAZ | --attributes all B/pt | × LAZ |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as work:
        for point_format in range(11):
            data = filled(scan, point_format)
            las, laz = os.path.join(work, f"{point_format}.las"), os.path.join(work, f"{point_format}.laz")
            data.write(las)
            data.write(laz)
            n, laz_size = len(data.points), os.path.getsize(laz)
            default, _, _ = set_bytes.build(a.binary, las, ["-q", "--threads", "2"], os.path.join(work, "default"))
            every, _, _ = set_bytes.build(a.binary, las, ["-q", "--threads", "2", "--attributes", "all"], os.path.join(work, "all"))
            dims = len(list(data.point_format.dimension_names))
            print(f"| {point_format} | {dims} | {laz_size / n:.2f} | {default / n:.2f} | {default / laz_size:.2f} | "
                  f"{every / n:.2f} | {every / laz_size:.2f} |", flush=True)


if __name__ == "__main__":
    main()
