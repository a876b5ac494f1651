#!/usr/bin/env python3
"""Server throughput benchmark: surfcast-serve against nginx.

wrk on loopback, 64 concurrent keep-alive connections fetching random node
blocks of a real tile set, against nginx (Debian) serving the same blocks.bin
with Range in the same run. The tile set: lion_takanawa.copc.laz tiled 3 x 2
(2.05 M points, decoded with laspy + lazrs) built by surfcast-build.

Three runs of --duration seconds each, one after the other:
  surfcast /nodes/{key}        one request per node block (the server's own route)
  surfcast blocks.bin + Range  the same bytes the static-host way
  nginx blocks.bin + Range     the reference, with sendfile off and on
Target: surfcast >= 0.8x nginx's requests/s with no errors.

Usage: bench/setup_venv.sh && bench/.venv/bin/python bench/serve_bench.py [--duration 10]
"""
import argparse
import os
import platform
import random
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from build_bench import DATA, ROOT, tiled_las  # noqa: E402


def nodes_of(set_dir):
    """(key, offset, size) of every node, parsed from hierarchy.bin (docs/FORMAT.md)."""
    data = open(os.path.join(set_dir, "hierarchy.bin"), "rb").read()
    assert data[:4] == b"SCHY"
    pages = struct.unpack_from("<I", data, 12)[0]
    out = {}
    for p in range(pages):
        offset, count, _ = struct.unpack_from("<QII", data, 32 + 16 * p)
        for i in range(count):
            r = offset + 64 * i
            level = data[r]
            x, y, z = struct.unpack_from("<III", data, r + 4)
            boff, bsize = struct.unpack_from("<QI", data, r + 16)
            out[f"{level}-{x}-{y}-{z}"] = (boff, bsize)
    return [(k, o, s) for k, (o, s) in sorted(out.items())]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port):
    for _ in range(100):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    sys.exit(f"nothing listens on {port}")


LUA = r"""
local lines = {}
for line in io.lines("%s") do lines[#lines + 1] = line end
math.randomseed(os.time())
request = function()
  local l = lines[math.random(#lines)]
  local path, range = l:match("([^ ]+) ?(.*)")
  if range ~= "" then
    return wrk.format("GET", path, {["Range"] = "bytes=" .. range})
  end
  return wrk.format("GET", path)
end
"""


def wrk(port, lines, work, name, duration):
    paths = os.path.join(work, name + ".txt")
    with open(paths, "w") as f:
        f.write("\n".join(lines) + "\n")
    script = os.path.join(work, name + ".lua")
    with open(script, "w") as f:
        f.write(LUA % paths)
    out = subprocess.run(["wrk", "-t2", "-c64", f"-d{duration}s", "--latency", "-s", script, f"http://127.0.0.1:{port}"],
                         capture_output=True, text=True, check=True).stdout

    def unit(v, u):
        return float(v) * {"us": 1e-3, "ms": 1.0, "s": 1e3}[u]
    lat = dict(re.findall(r"^\s+(50|99)%\s+([\d.]+\w+)", out, re.M))
    ms = {k: unit(*re.match(r"([\d.]+)(\w+)", v).groups()) for k, v in lat.items()}
    rps = float(re.search(r"Requests/sec:\s+([\d.]+)", out).group(1))
    transfer = re.search(r"Transfer/sec:\s+([\d.]+)(\w+)", out)
    mb = float(transfer.group(1)) * {"B": 1e-6, "KB": 1.024e-3, "MB": 1.048576, "GB": 1073.741824}[transfer.group(2)]
    errors = 0
    m = re.search(r"Non-2xx or 3xx responses: (\d+)", out)
    errors += int(m.group(1)) if m else 0
    m = re.search(r"Socket errors: connect (\d+), read (\d+), write (\d+), timeout (\d+)", out)
    errors += sum(int(v) for v in m.groups()) if m else 0
    return {"rps": rps, "mbs": mb, "p50": ms.get("50"), "p99": ms.get("99"), "errors": errors, "raw": out}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=int, default=10)
    ap.add_argument("--tiles", default="3x2")
    args = ap.parse_args()
    for tool in ("wrk", "nginx"):
        if not shutil.which(tool) and not os.path.exists("/usr/sbin/nginx"):
            sys.exit(f"{tool} missing: apt-get install wrk nginx-light")
    work = tempfile.mkdtemp(prefix="surfcast-serve-bench-", dir=os.path.join(ROOT, "bench"))
    os.chmod(work, 0o755)  # nginx workers run as www-data
    procs = []
    try:
        tx, ty = (int(v) for v in args.tiles.split("x"))
        las = os.path.join(work, "lion.las")
        points = tiled_las(os.path.join(DATA, "lion_takanawa.copc.laz"), tx, ty, las)
        sets = os.path.join(work, "sets")
        subprocess.run([os.path.join(ROOT, "build/bin/surfcast-build"), "-q", las, "-o", os.path.join(sets, "lion")],
                       check=True, stdout=subprocess.DEVNULL)
        os.remove(las)
        nodes = nodes_of(os.path.join(sets, "lion"))
        sizes = sorted(s for _, _, s in nodes)

        port = free_port()
        procs.append(subprocess.Popen([os.path.join(ROOT, "build/bin/surfcast-serve"), sets, "--bind", f"127.0.0.1:{port}",
                                       "--log", "quiet"]))
        # nginx twice: Debian's default (sendfile on) and sendfile off, which is
        # 5x faster on this machine's loopback; the better one is the reference.
        nginx = shutil.which("nginx") or "/usr/sbin/nginx"
        nports = {}
        for sendfile in ("on", "off"):
            nport = nports[sendfile] = free_port()
            prefix = os.path.join(work, "nginx-" + sendfile)
            os.makedirs(prefix)
            conf = os.path.join(prefix, "nginx.conf")
            with open(conf, "w") as f:
                f.write(f"""worker_processes auto;
pid {prefix}/nginx.pid;
error_log {prefix}/error.log;
daemon off;
events {{ worker_connections 1024; }}
http {{
  access_log off;
  sendfile {sendfile};
  tcp_nopush on;
  output_buffers 2 256k;
  keepalive_requests 100000;
  keepalive_timeout 30;
  client_body_temp_path {prefix}/tmp;
  server {{ listen 127.0.0.1:{nport}; root {sets}; location /sets/ {{ alias {sets}/; }} }}
}}
""")
            procs.append(subprocess.Popen([nginx, "-c", conf, "-p", prefix], stderr=subprocess.DEVNULL))
        wait_port(port)
        for p in nports.values():
            wait_port(p)

        random.seed(1)
        node_paths = [f"/sets/lion/nodes/{k}" for k, _, _ in nodes]
        range_paths = [f"/sets/lion/blocks.bin {o}-{o + s - 1}" for _, o, s in nodes]
        results = [
            ("surfcast `/nodes/{key}`", wrk(port, node_paths, work, "nodes", args.duration)),
            ("surfcast `blocks.bin` + Range", wrk(port, range_paths, work, "ranges", args.duration)),
            ("nginx `blocks.bin` + Range, sendfile off", wrk(nports["off"], range_paths, work, "nginx-off", args.duration)),
            ("nginx `blocks.bin` + Range, sendfile on (Debian default)", wrk(nports["on"], range_paths, work, "nginx-on", args.duration)),
        ]
        cpu = open("/proc/cpuinfo").read()
        model = re.search(r"model name\s*: (.*)", cpu).group(1)
        nginx_rps = max(results[2][1]["rps"], results[3][1]["rps"])
        print(f"### Server throughput, {len(nodes)} node blocks of a {points / 1e6:.2f} M-point set\n")
        print(f"- machine: {model}, {os.cpu_count()} cores, {platform.platform()}; wrk and the server share the cores")
        print("- command: `bench/.venv/bin/python bench/serve_bench.py` "
              f"(`wrk -t2 -c64 -d{args.duration}s --latency`, random node per request)")
        print(f"- block sizes: median {sizes[len(sizes) // 2] / 1024:.0f} KiB, max {sizes[-1] / 1024:.0f} KiB\n")
        print("| server | requests/s | MB/s | p50 ms | p99 ms | errors | vs best nginx |")
        print("|---|---|---|---|---|---|---|")
        for name, r in results:
            print(f"| {name} | {r['rps']:.0f} | {r['mbs']:.0f} | {r['p50']:.2f} | {r['p99']:.2f} | {r['errors']} | "
                  f"{r['rps'] / nginx_rps:.2f}x |")
        if os.environ.get("SERVE_BENCH_RAW"):
            for name, r in results:
                print(f"\n#### {name}\n```\n{r['raw']}```", file=sys.stderr)
    finally:
        for p in procs:
            p.send_signal(signal.SIGTERM)
            p.wait(timeout=10)
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
