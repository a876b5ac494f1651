#!/usr/bin/env python3
"""Streaming over TLS from nginx: HTTP/1.1 against HTTP/2, side by side.

The built-in scene at --points, served by Debian's nginx over TLS on two
loopback ports, HTTP/2 on one and HTTP/1.1 only on the other (a CA and a
server certificate made here with openssl). surfcast-view --headless URL
--lod 1 streams it from a close-up and from an overview, each until
converged, alternating the protocols for --rounds rounds. Per run: time to
the first image and to convergence (from the program's start, so the TLS
handshake and opening the set count), requests and bytes from its JSON
lines. nginx's access log confirms each protocol.

Writes bench/report/https.md (and prints it).

Usage: bench/.venv/bin/python bench/https_bench.py [--points 3000000] [--rounds 3]
"""
import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time

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
        f" ssl_certificate_key {tmp}/server.key; access_log {tmp}/access.log combined; root {www}; }}\n"
        for i, p in enumerate(ports))
    with open(f"{tmp}/nginx.conf", "w") as fh:
        fh.write(f"daemon off; master_process off; worker_processes 1; pid {tmp}/nginx.pid; error_log stderr notice;\n"
                 "events { worker_connections 256; }\n"
                 f"http {{ client_body_temp_path {tmp}/b; proxy_temp_path {tmp}/p; fastcgi_temp_path {tmp}/f;"
                 f" uwsgi_temp_path {tmp}/u; scgi_temp_path {tmp}/s;\n{servers}}}\n")
    proc = subprocess.Popen(["/usr/sbin/nginx", "-e", "stderr", "-p", tmp, "-c", f"{tmp}/nginx.conf"],
                            stderr=subprocess.DEVNULL)
    time.sleep(1)
    return proc, ports


def stream(url, camera, ca, out):
    start = time.time()
    res = subprocess.run([os.path.join(BIN, "surfcast-view"), "--headless", url, camera, "--lod", "1", "--size", "640x360",
                          "--ca-file", ca, "--max-wait", "120", "--out", out], check=True, capture_output=True, text=True)
    wall = time.time() - start
    lines = json_lines(res.stdout)
    assert lines and lines[-1]["converged"], res.stdout[-500:]
    return {"first": lines[0]["time_s"], "converged": lines[-1]["time_s"], "wall": wall,
            "requests": lines[-1]["requests"], "bytes": lines[-1]["bytes_downloaded"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=3000000)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        www = os.path.join(tmp, "www")
        os.makedirs(os.path.join(www, "sets"))
        subprocess.run([os.path.join(BIN, "surfcast-build"), "-q", "--default-scene", "--scene-points", str(args.points), "-o",
                        os.path.join(www, "sets", "scene")], check=True, capture_output=True)
        certificates(tmp)
        proc, ports = nginx(tmp, www)
        try:
            runs = {}
            for _ in range(args.rounds):
                for proto, port in (("HTTP/2", ports[0]), ("HTTP/1.1", ports[1])):
                    for view, camera in VIEWS.items():
                        r = stream(f"https://127.0.0.1:{port}/sets/scene", camera, f"{tmp}/ca.pem", f"{tmp}/f.png")
                        runs.setdefault((view, proto), []).append(r)
                        print(f"{view} {proto}: first {r['first']:.2f} s, converged {r['converged']:.2f} s, "
                              f"{r['requests']} requests, {r['bytes']} bytes", file=sys.stderr)
            log = open(f"{tmp}/access.log").read()
            assert 'HTTP/2.0" 206' in log and 'HTTP/1.1" 206' in log, "a protocol did not serve ranges"
        finally:
            proc.terminate()
            proc.wait()
    lines = [f"The built-in scene at {args.points} points from nginx over TLS on loopback, `--lod 1`, 640x360, 6 "
             f"connections; median of {args.rounds} alternating rounds (times from the program's start).", "",
             "| view | protocol | first image s | converged s | requests | MB |", "|---|---|---:|---:|---:|---:|"]
    for (view, proto), rs in runs.items():
        med = lambda k: statistics.median(r[k] for r in rs)
        lines.append(f"| {view} | {proto} | {med('first'):.2f} | {med('converged'):.2f} | {med('requests'):.0f} | "
                     f"{med('bytes') / 1e6:.1f} |")
    write_markdown("https.md", lines)


if __name__ == "__main__":
    main()
