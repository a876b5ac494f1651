#!/usr/bin/env python3
"""Streaming over TLS from nginx: HTTP/1.1 against HTTP/2, side by side;
surfcast-serve with TLS against plain HTTP; and the hierarchy pages a view
fetches.

The built-in scene at --points, served by Debian's nginx over TLS on two
loopback ports, HTTP/2 on one and HTTP/1.1 only on the other (a CA and a
server certificate made here with openssl), and by surfcast-serve twice,
with --tls-cert/--tls-key and without. Loopback has no latency, and a
CDN has tens of milliseconds of it, so each port is also reached through a
relay that holds every chunk for half of each --rtt in each direction (an
asyncio TCP relay in this process; TLS passes through it unchanged).
surfcast-view --headless URL --lod 1 streams the set from a close-up and
from an overview, each until converged, alternating the protocols for
--rounds rounds. Per run: time to the first image and to convergence (from
the program's start, so the TLS handshakes and opening the set count);
HTTP requests and TCP connections from nginx's access log (surfcast-serve
batches nodes into fewer requests, not counted); block bytes, and the
hierarchy bytes and pages fetched (the client fetches hierarchy pages as the
view reaches them) against hierarchy.bin's size. Without added latency,
`surfcast-build --info URL` also fetches and checks every block, one request
after another: bulk transfer time per server.

Writes bench/report/https.md (and prints it).

Usage: bench/.venv/bin/python bench/https_bench.py [--points 3000000] [--rounds 3] [--rtt 0,40]
"""
import argparse
import asyncio
import os
import socket
import ssl
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from accuracy_bench import BIN, write_markdown  # noqa: E402
from stream_bench import json_lines  # noqa: E402

VIEWS = {"overview": "--camera=12,-20,9,0,0,0.5,0,0,1,50", "close-up": "--camera=2,-3,1.2,0,0,0.5,0,0,1,50"}


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def certificates(tmp):
    ssl = lambda *a: subprocess.run(["openssl", *a], check=True, capture_output=True)
    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{tmp}/ca.key", "-out", f"{tmp}/ca.pem", "-days", "2",
        "-subj", "/CN=bench ca")
    ssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{tmp}/server.key", "-out", f"{tmp}/server.csr", "-subj",
        "/CN=127.0.0.1")
    with open(f"{tmp}/san.cnf", "w") as fh:
        fh.write("subjectAltName=IP:127.0.0.1\n")
    ssl("x509", "-req", "-in", f"{tmp}/server.csr", "-CA", f"{tmp}/ca.pem", "-CAkey", f"{tmp}/ca.key", "-CAcreateserial",
        "-out", f"{tmp}/server.pem", "-days", "2", "-extfile", f"{tmp}/san.cnf")


def nginx(tmp, www):
    ports = [free_port(), free_port()]
    servers = "".join(
        f" server {{ listen 127.0.0.1:{p} ssl{' http2' if i == 0 else ''}; ssl_certificate {tmp}/server.pem;"
        f" ssl_certificate_key {tmp}/server.key; access_log {tmp}/access.log conn; root {www}; }}\n"
        for i, p in enumerate(ports))
    with open(f"{tmp}/nginx.conf", "w") as fh:
        fh.write(f"daemon off; master_process off; worker_processes 1; pid {tmp}/nginx.pid; error_log stderr notice;\n"
                 "events { worker_connections 256; }\n"
                 f"http {{ client_body_temp_path {tmp}/b; proxy_temp_path {tmp}/p; fastcgi_temp_path {tmp}/f;"
                 f" uwsgi_temp_path {tmp}/u; scgi_temp_path {tmp}/s;\n"
                 " log_format conn '$connection $server_protocol $status $body_bytes_sent $request_uri';\n"
                 f"{servers}}}\n")
    proc = subprocess.Popen(["/usr/sbin/nginx", "-e", "stderr", "-p", tmp, "-c", f"{tmp}/nginx.conf"],
                            stderr=subprocess.DEVNULL)
    time.sleep(1)
    return proc, ports


class Relay:
    """TCP relays to loopback ports, each chunk held `delay` seconds per
    direction, order and throughput kept (a queue per direction)."""

    def __init__(self):
        self.loop = asyncio.new_event_loop()
        threading.Thread(target=self.loop.run_forever, daemon=True).start()

    def start(self, target, delay):
        port = free_port()
        asyncio.run_coroutine_threadsafe(
            asyncio.start_server(lambda r, w: self._connect(r, w, target, delay), "127.0.0.1", port), self.loop).result()
        return port

    async def _connect(self, client_reader, client_writer, target, delay):
        try:
            server_reader, server_writer = await asyncio.open_connection("127.0.0.1", target)
        except OSError:
            client_writer.close()
            return
        await asyncio.gather(self._pump(client_reader, server_writer, delay),
                             self._pump(server_reader, client_writer, delay), return_exceptions=True)

    async def _pump(self, reader, writer, delay):
        queue = asyncio.Queue()

        async def read():
            while True:
                try:
                    data = await reader.read(1 << 16)
                except OSError:
                    data = b""
                await queue.put((self.loop.time() + delay, data))
                if not data:
                    return

        async def write():
            while True:
                due, data = await queue.get()
                await asyncio.sleep(max(0.0, due - self.loop.time()))
                try:
                    if not data:
                        writer.write_eof()
                        return
                    writer.write(data)
                    await writer.drain()
                except OSError:
                    return

        await asyncio.gather(read(), write(), return_exceptions=True)


def serve(tmp, www, tls):
    port = free_port()
    args = [os.path.join(BIN, "surfcast-serve"), www, "--bind", f"127.0.0.1:{port}", "--log", "errors"]
    if tls:
        args += ["--tls-cert", f"{tmp}/server.pem", "--tls-key", f"{tmp}/server.key"]
    proc = subprocess.Popen(args, stderr=subprocess.DEVNULL)
    time.sleep(1)
    return proc, port


def info_seconds(url, ca):
    start = time.time()
    subprocess.run([os.path.join(BIN, "surfcast-build"), "--info", url, "--ca-file", ca], check=True, capture_output=True)
    return time.time() - start


def download_seconds(url, ca):
    """All of blocks.bin in one GET: raw transfer, TLS included."""
    context = ssl.create_default_context(cafile=ca)
    start = time.time()
    with urllib.request.urlopen(url + "/blocks.bin", context=context if url.startswith("https") else None) as r:
        while r.read(1 << 20):
            pass
    return time.time() - start


def log_since(path, offset):
    with open(path) as fh:
        fh.seek(offset)
        entries = [line.split() for line in fh if line.strip()]
    return entries, os.path.getsize(path)


def stream(url, camera, ca, out):
    start = time.time()
    res = subprocess.run([os.path.join(BIN, "surfcast-view"), "--headless", url, camera, "--lod", "1", "--size", "640x360",
                          "--ca-file", ca, "--max-wait", "300", "--out", out], check=True, capture_output=True, text=True)
    wall = time.time() - start
    lines = json_lines(res.stdout)
    assert lines and lines[-1]["converged"], res.stdout[-500:]
    last = lines[-1]
    return {"first": lines[0]["time_s"], "converged": last["time_s"], "wall": wall, "bytes": last["bytes_downloaded"],
            "hierarchy_bytes": last["hierarchy_bytes"], "pages": last["hierarchy_pages"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=3000000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--rtt", default="0,40", help="round-trip times to add, in milliseconds")
    ap.add_argument("--page-depth", type=int, default=5, help="the set's levels per hierarchy page")
    args = ap.parse_args()
    rtts = [float(r) for r in args.rtt.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        www = os.path.join(tmp, "www")
        os.makedirs(os.path.join(www, "sets"))
        subprocess.run([os.path.join(BIN, "surfcast-build"), "-q", "--default-scene", "--scene-points", str(args.points),
                        "--page-depth", str(args.page_depth), "-o", os.path.join(www, "sets", "scene")],
                       check=True, capture_output=True)
        hierarchy_size = os.path.getsize(os.path.join(www, "sets", "scene", "hierarchy.bin"))
        certificates(tmp)
        proc, ports = nginx(tmp, www)
        plain, plain_port = serve(tmp, os.path.join(www, "sets"), False)
        secure, secure_port = serve(tmp, os.path.join(www, "sets"), True)
        servers = {"nginx HTTP/2": ("https", ports[0], "HTTP/2.0"), "nginx HTTP/1.1": ("https", ports[1], "HTTP/1.1"),
                   "surfcast-serve TLS": ("https", secure_port, None), "surfcast-serve plain": ("http", plain_port, None)}
        relay = Relay()
        log = f"{tmp}/access.log"
        offset = 0
        try:
            runs, infos = {}, {}
            for _ in range(args.rounds):
                for rtt in rtts:
                    for name, (scheme, port, logged) in servers.items():
                        via = relay.start(port, rtt / 2000) if rtt > 0 else port
                        url = f"{scheme}://127.0.0.1:{via}/sets/scene"
                        if rtt == 0:
                            infos.setdefault(name, []).append((info_seconds(url, f"{tmp}/ca.pem"),
                                                               download_seconds(url, f"{tmp}/ca.pem")))
                            entries, offset = log_since(log, offset)
                        for view, camera in VIEWS.items():
                            r = stream(url, camera, f"{tmp}/ca.pem", f"{tmp}/f.png")
                            entries, offset = log_since(log, offset)
                            if logged:
                                assert entries and all(e[1] == logged for e in entries), f"{name}: nginx logged {entries[:1]}"
                            r["requests"] = len(entries) if logged else None
                            r["connections"] = len({e[0] for e in entries}) if logged else None
                            runs.setdefault((rtt, view, name), []).append(r)
                            print(f"rtt {rtt:g} ms {view} {name}: first {r['first']:.2f} s, converged "
                                  f"{r['converged']:.2f} s, {r['requests']} requests on {r['connections']} "
                                  f"connections, {r['bytes']} bytes, hierarchy {r['hierarchy_bytes']} bytes in "
                                  f"{r['pages']} pages", file=sys.stderr)
        finally:
            for p in (proc, plain, secure):
                p.terminate()
                p.wait()
    lines = [f"The built-in scene at {args.points} points (hierarchy.bin {hierarchy_size} bytes, pages of "
             f"{args.page_depth} levels) from nginx over TLS on loopback, through a relay adding the round-trip time, "
             f"`--lod 1`, 640x360; median of {args.rounds} alternating rounds (times from the program's start, "
             "requests and connections from nginx's log).", "",
             "| RTT ms | view | server | first image s | converged s | requests | connections | block MB | "
             "hierarchy KB (pages) |",
             "|---:|---|---|---:|---:|---:|---:|---:|---:|"]
    for (rtt, view, name), rs in sorted(runs.items(), key=lambda kv: (kv[0][0], kv[0][1])):
        med = lambda k: statistics.median(r[k] for r in rs)
        count = lambda k: "–" if rs[0][k] is None else f"{med(k):.0f}"
        lines.append(f"| {rtt:g} | {view} | {name} | {med('first'):.2f} | {med('converged'):.2f} | "
                     f"{count('requests')} | {count('connections')} | {med('bytes') / 1e6:.1f} | "
                     f"{med('hierarchy_bytes') / 1e3:.1f} ({med('pages'):.0f}) |")
    if infos:
        lines += ["", "Bulk, no added latency, median seconds: `surfcast-build --info URL` (every block fetched, "
                  "decoded and checked, one request after another) and all of blocks.bin in one GET (Python's urllib).",
                  "", "| server | --info s | blocks.bin s |", "|---|---:|---:|"]
        lines += [f"| {name} | {statistics.median(t[0] for t in ts):.2f} | {statistics.median(t[1] for t in ts):.3f} |"
                  for name, ts in infos.items()]
    write_markdown("https.md", lines)


if __name__ == "__main__":
    main()
