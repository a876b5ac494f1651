"""A real S3 store for the Python tests and benchmarks: SeaweedFS (`weed mini`,
which scripts/install-seaweedfs.sh builds) serving one bucket from a scratch
folder on loopback, every port derived from `port` (pick one per program, so
that programs running beside each other do not meet), one user who may do
anything. tests/store_support.h is the C++ tests' twin.

    store = SeaweedFs(work, port=18533, bucket="surfcast")
    env = dict(os.environ, **store.environment())   # AWS_* for the programs
    store.put("in/a.laz", path); store.get("sets/x/tileset.json"); store.stop()
"""
import json
import os
import socket
import subprocess
import time

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
WEED = os.path.join(REPO, "build", "seaweedfs", "weed")
KEY, SECRET = "surfcastkey", "surfcast-secret-never-shown"


class SeaweedFs:
    def __init__(self, work, port, bucket):
        if not os.path.exists(WEED):
            raise RuntimeError(f"{WEED} is missing: scripts/install-seaweedfs.sh builds it")
        self.port, self.bucket = port, bucket
        self.endpoint = f"http://127.0.0.1:{port}"
        config = os.path.join(work, "s3.json")
        with open(config, "w") as f:
            json.dump({"identities": [{"name": "writer", "credentials": [{"accessKey": KEY, "secretKey": SECRET}],
                                       "actions": ["Admin", "Read", "Write", "List", "Tagging"]}]}, f)
        os.makedirs(os.path.join(work, "data"), exist_ok=True)
        # A store left running on the port (a test killed before it stopped
        # its own) would answer in place of this one, with its old objects.
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                raise RuntimeError(f"port {port} is taken (a SeaweedFS left running?): stop what holds it first")
        # Every port fixed away from the defaults, which other programs take.
        ports = {"-s3.port": port, "-s3.port.iceberg": port + 48, "-master.port": port + 1000, "-volume.port": port + 47,
                 "-filer.port": port + 55, "-admin.port": port + 13, "-webdav.port": port - 33, "-debug.port": port + 27,
                 "-s3.metricsPort": port + 968}
        self.log = os.path.join(work, "weed.log")
        with open(self.log, "w") as log:
            self.proc = subprocess.Popen([WEED, "mini", "-dir=" + os.path.join(work, "data"), "-ip=127.0.0.1", "-ip.bind=127.0.0.1",
                                          "-s3.config=" + config, "-bucket=" + bucket, "-admin.port.legacy=0"] +
                                         [f"{k}={v}" for k, v in ports.items()], stdout=log, stderr=subprocess.STDOUT)
        # Ready when the bucket answers a signed listing (the S3 port opens
        # before the filer behind it is up).
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"SeaweedFS ended at start; its log: {self.log}")
            if self._curl([f"{self.endpoint}/{bucket}?list-type=2&prefix=none%2F"]).returncode == 0:
                return
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"SeaweedFS did not answer within 60 s; its log: {self.log}")

    def environment(self):
        return {"AWS_ENDPOINT_URL": self.endpoint, "AWS_ACCESS_KEY_ID": KEY, "AWS_SECRET_ACCESS_KEY": SECRET, "AWS_REGION": "us-east-1"}

    def _curl(self, args):
        # curl's own SigV4 (libcurl's, as the programs sign).
        return subprocess.run(["curl", "-sf", "--aws-sigv4", "aws:amz:us-east-1:s3", "--user", f"{KEY}:{SECRET}",
                               "-H", "x-amz-content-sha256: UNSIGNED-PAYLOAD"] + args, capture_output=True)

    def put(self, key, path):
        r = self._curl(["-T", path, f"{self.endpoint}/{self.bucket}/{key}"])
        if r.returncode != 0:
            raise RuntimeError(f"PUT {key}: curl exit {r.returncode}: {r.stderr.decode(errors='replace')}")

    def put_folder(self, folder, prefix):
        """A folder's files as objects under `prefix` (what `aws s3 sync` does)."""
        for f in sorted(os.listdir(folder)):
            self.put(f"{prefix}/{f}", os.path.join(folder, f))

    def get(self, key):
        """The object's bytes, or None where there is none."""
        r = self._curl([f"{self.endpoint}/{self.bucket}/{key}"])
        return r.stdout if r.returncode == 0 else None

    def keys(self, prefix):
        import re
        import urllib.parse
        r = self._curl([f"{self.endpoint}/{self.bucket}?list-type=2&prefix={urllib.parse.quote(prefix, safe='')}"])
        return re.findall(r"<Key>([^<]*)</Key>", r.stdout.decode())

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
