#!/usr/bin/env python3
"""Tile latency while the export route refuses 200 requests at a time.

A generated set (surfcast-build --default-scene --scene-points N) served by
surfcast-serve with --export-max-points below its size; one keep-alive
client fetches random node blocks one after another and records each
request's latency, first alone, then while 8 other connections keep sending
whole-set export requests in bursts of 200 (each refused: 413, or 503 with
every place taken). Several servers, one after the other, on the same set:
pass each binary to compare (e.g. a build before and after a change).

Usage: bench/export_refusal_bench.py --serve build/bin/surfcast-serve [--serve OTHER] [--points 2e7] [--seconds 10]
"""
import argparse
import http.client
import os
import platform
import random
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BURST, SENDERS = 200, 8


def node_keys(set_dir):
    """Every node's key, from hierarchy.bin (docs/FORMAT.md)."""
    data = open(os.path.join(set_dir, "hierarchy.bin"), "rb").read()
    pages = struct.unpack_from("<I", data, 12)[0]
    keys = []
    for p in range(pages):
        offset, count, _ = struct.unpack_from("<QII", data, 32 + 16 * p)
        for i in range(count):
            r = offset + 64 * i
            x, y, z = struct.unpack_from("<III", data, r + 4)
            keys.append(f"{data[r]}-{x}-{y}-{z}")
    return keys


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tile_latencies(port, keys, seconds):
    c = http.client.HTTPConnection("127.0.0.1", port)
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t = time.perf_counter()
        c.request("GET", f"/sets/big/nodes/{random.choice(keys)}")
        r = c.getresponse()
        r.read()
        assert r.status == 200, r.status
        out.append((time.perf_counter() - t) * 1e3)
    return out


def refuse(port, stop, counts, lock):
    c = http.client.HTTPConnection("127.0.0.1", port)
    while not stop.is_set():
        for _ in range(BURST // SENDERS):
            c.request("GET", "/sets/big/export.laz")
            r = c.getresponse()
            r.read()
            with lock:
                counts[r.status] = counts.get(r.status, 0) + 1


def pct(v, p):
    v = sorted(v)
    return v[min(len(v) - 1, int(p / 100 * len(v)))]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--serve", action="append", required=True, help="a surfcast-serve binary (repeat to compare)")
    ap.add_argument("--points", type=float, default=2e7)
    ap.add_argument("--seconds", type=float, default=10)
    ap.add_argument("--work", default=None, help="folder to keep the set in (reused when it holds one)")
    a = ap.parse_args()
    work = a.work or tempfile.mkdtemp(prefix="refusal-bench-")
    set_dir = os.path.join(work, "sets", "big")
    if not os.path.exists(os.path.join(set_dir, "tileset.json")):
        t = time.time()
        subprocess.run([os.path.join(ROOT, "build/bin/surfcast-build"), "--default-scene", "--scene-points", str(int(a.points)),
                        "-q", "-o", set_dir], check=True)
        print(f"built {int(a.points)} points in {time.time() - t:.0f} s", file=sys.stderr)
    keys = node_keys(set_dir)
    hierarchy = os.path.getsize(os.path.join(set_dir, "hierarchy.bin"))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, {platform.platform()}")
    print(f"set: {int(a.points)} scene points, {len(keys)} nodes, hierarchy.bin {hierarchy} bytes")
    print("| server | exports refused | tile requests | p50 ms | p90 ms | p99 ms | max ms |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for serve in a.serve:
        port = free_port()
        proc = subprocess.Popen([serve, os.path.join(work, "sets"), "--bind", f"127.0.0.1:{port}", "--log", "quiet",
                                 "--export-max-points", "1000000", "--no-web"])
        try:
            for _ in range(100):
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                    break
                except OSError:
                    time.sleep(0.05)
            tile_latencies(port, keys, 1)  # warm the page cache and the set's snapshot
            for refusing in (False, True):
                stop, lock, counts = threading.Event(), threading.Lock(), {}
                senders = [threading.Thread(target=refuse, args=(port, stop, counts, lock)) for _ in range(SENDERS if refusing else 0)]
                for s in senders:
                    s.start()
                lat = tile_latencies(port, keys, a.seconds)
                stop.set()
                for s in senders:
                    s.join()
                refused = ", ".join(f"{n} x {st}" for st, n in sorted(counts.items())) if refusing else "none"
                print(f"| `{serve}` | {refused} | {len(lat)} | {pct(lat, 50):.2f} | {pct(lat, 90):.2f} | {pct(lat, 99):.2f} | "
                      f"{max(lat):.2f} |", flush=True)
        finally:
            proc.terminate()
            proc.wait()


if __name__ == "__main__":
    main()
