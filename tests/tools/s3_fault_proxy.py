#!/usr/bin/env python3
"""A proxy in front of an S3 store that fails a share of the requests, for the
object-store fault tests (tests/store_test.cpp).

Usage: s3_fault_proxy.py PORT UPSTREAM_PORT SHARE SEED COUNTS_FILE [METHODS]

Listens on loopback PORT and says "listening" on stderr when it does. Each
request is, with probability SHARE, answered with one fault, drawn evenly:
  slowdown  503 SlowDown, before the store sees the request;
  error     500 InternalError, after the store has answered it (applied);
  reset     the connection reset, after the store has answered it (applied).
Every other request goes to the store unchanged (its Host header included,
which the signature covers) and its answer comes back, as do requests of
methods not in METHODS (a comma-separated list; default: every method).
COUNTS_FILE gets the count of each fault kind and of the requests forwarded,
as JSON, rewritten after each request.
"""
import ctypes
import http.client
import http.server
import json
import os
import random
import socket
import socketserver
import struct
import sys
import threading

PORT = int(sys.argv[1])
UPSTREAM = int(sys.argv[2])
SHARE = float(sys.argv[3])
RANDOM = random.Random(int(sys.argv[4]))
COUNTS_FILE = sys.argv[5]
METHODS = set(sys.argv[6].split(",")) if len(sys.argv) > 6 else None
COUNTS = {"slowdown": 0, "error": 0, "reset": 0, "forwarded": 0}
LOCK = threading.Lock()
HOP = {"connection", "keep-alive", "transfer-encoding", "te", "trailer", "upgrade", "proxy-connection"}
ERROR = b'<?xml version="1.0" encoding="UTF-8"?><Error><Code>%s</Code><Message>injected by the fault proxy</Message></Error>'


def draw(method):
    with LOCK:
        if (METHODS is not None and method not in METHODS) or RANDOM.random() >= SHARE:
            COUNTS["forwarded"] += 1
            COUNTS["forwarded " + method] = COUNTS.get("forwarded " + method, 0) + 1
            kind = None
        else:
            kind = RANDOM.choice(["slowdown", "error", "reset"])
            COUNTS[kind] += 1
        save()
    return kind


def save():
    """Rewrites COUNTS_FILE whole (a reader never sees half of it)."""
    with open(COUNTS_FILE + ".partial", "w") as f:
        json.dump(COUNTS, f)
    os.replace(COUNTS_FILE + ".partial", COUNTS_FILE)


class Handler(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"

    def log_message(self, *args):
        pass

    def answer(self, status, body, headers=(), length=None):
        self.send_response(status)
        for name, value in headers:
            self.send_header(name, value)
        # A HEAD's answer keeps the store's Content-Length: the object's size.
        self.send_header("Content-Length", str(len(body) if length is None else length))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def forward(self):
        length = int(self.headers.get("Content-Length", 0) or 0)
        body = self.rfile.read(length) if length else None
        kind = draw(self.command)
        if kind == "slowdown":
            self.answer(503, ERROR % b"SlowDown", [("Content-Type", "application/xml")])
            return
        upstream = http.client.HTTPConnection("127.0.0.1", UPSTREAM, timeout=60)
        headers = {k: v for k, v in self.headers.items() if k.lower() not in HOP}
        upstream.request(self.command, self.path, body=body, headers=headers)
        response = upstream.getresponse()
        data = response.read()
        upstream.close()
        if kind == "error":
            self.answer(500, ERROR % b"InternalError", [("Content-Type", "application/xml")])
        elif kind == "reset":
            # RST instead of FIN: the client sees the connection reset.
            self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            self.close_connection = True
        else:
            kept = [(k, v) for k, v in response.getheaders() if k.lower() not in HOP and k.lower() != "content-length"]
            self.answer(response.status, data, kept, response.getheader("Content-Length") if self.command == "HEAD" else None)

    do_GET = do_PUT = do_POST = do_DELETE = do_HEAD = forward


class Server(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = True


# It dies with the test that started it (PR_SET_PDEATHSIG, SIGKILL), however
# that ends: a proxy left running would hold the port the next test needs.
ctypes.CDLL("libc.so.6").prctl(1, 9)
server = Server(("127.0.0.1", PORT), Handler)
save()
print("listening", file=sys.stderr, flush=True)
server.serve_forever()
