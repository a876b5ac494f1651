"""What the bytes benchmarks share: their arguments, a build's set bytes and
the input's own LAZ bytes.

A set's bytes are hierarchy.bin + blocks.bin (tileset.json's counts); an
input's LAZ bytes are the LAZ file as given, or a LAS file compressed by
laspy's lazrs (the `laz` crate that LASzip-compatible writers share).
"""
import argparse
import json
import os
import subprocess

import laspy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def arguments(doc, scans=None):
    """--build and --data, and the scans named (default `scans`) where given."""
    p = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--build", default=os.path.join(ROOT, "build"), help="the build folder (default build)")
    p.add_argument("--data", default=os.path.join(ROOT, "..", "shared", "data"), help="the scans (default ../shared/data)")
    if scans is not None:
        p.add_argument("scans", nargs="*", default=scans, help="scans in --data (default: %(default)s)")
    a = p.parse_args()
    a.binary = os.path.join(a.build, "bin", "surfcast-build")
    if not os.access(a.binary, os.X_OK):
        p.error(f"no surfcast-build in {a.build}/bin: build the project first (ninja -C build)")
    return a


def build(binary, scan, args, out):
    """Builds `scan` into `out`; returns the set's bytes, its tileset.json and the build's stdout."""
    run = subprocess.run([binary, scan, *args, "-o", out], capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"surfcast-build {scan} {' '.join(args)} failed:\n{run.stdout}{run.stderr}")
    info = json.load(open(os.path.join(out, "tileset.json")))
    return info["hierarchy"]["bytes"] + info["blocks"]["bytes"], info, run.stdout


def laz_bytes(scan, work):
    """The bytes of `scan` as LAZ: its own where it is one, else written to `work`."""
    if scan.endswith(".laz"):
        return os.path.getsize(scan)
    laz = os.path.join(work, os.path.basename(scan) + ".laz")
    laspy.read(scan).write(laz)
    return os.path.getsize(laz)
