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
    rec = np.zeros(len(scan.points), dtype=out.points.array.dtype)
    names = set(rec.dtype.names)
    for name in scan.point_format.dimension_names:
        if name in names:
            rec[name] = np.asarray(scan[name])
    # LAS 1.4 formats keep these bits apart from the classification.
    for flag in ("synthetic", "key_point", "withheld"):
        if flag in names:
            rec[flag] = np.asarray(scan[flag])
    angle = np.asarray(scan.scan_angle_rank).astype(np.float64)
    if "scan_angle" in names:
        rec["scan_angle"] = np.round(angle / 0.006).astype(np.int16)
    if "nir" in names:
        rec["nir"] = np.asarray(scan.red)
    if "wavepacket_index" in names:
        rec["wavepacket_index"] = 1
        rec["wavepacket_size"] = 256
        order = np.argsort(np.asarray(scan.gps_time), kind="stable")
        offset = np.empty(len(order), dtype=np.uint64)
        offset[order] = 256 * np.arange(len(order), dtype=np.uint64)
        rec["wavepacket_offset"] = offset
        rec["return_point_wave_location"] = 1000.0 * np.asarray(scan.return_number)
        theta = np.radians(angle)
        rec["x_t"], rec["y_t"], rec["z_t"] = np.sin(theta) * 1e-4, 0.0, -np.cos(theta) * 1e-4
    out.points = laspy.ScaleAwarePointRecord(rec, header.point_format, header.scales, header.offsets)
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
