#!/usr/bin/env python3
"""scripts/surfcast-dask on a real Dask cluster on loopback: a scheduler and
two worker processes started as a cluster starts them (`dask scheduler`,
`dask worker`), against surfcast-build in one process.

Run by ctest (dask_test) with SURFCAST_BUILD (the build folder),
SURFCAST_DATA_DIR and SURFCAST_TEST_PYTHON (the test venv, for
tests/tools/split_laz.py). Only the standard library: the cluster's programs
come from the driver's own environment, which `surfcast-dask --help` makes.
"""
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import unittest

REPO = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))
BUILD = os.environ.get("SURFCAST_BUILD", os.path.join(REPO, "build"))
SURFCAST_BUILD = os.path.join(BUILD, "bin", "surfcast-build")
DRIVER = os.path.join(REPO, "scripts", "surfcast-dask")
DATA = os.environ.get("SURFCAST_DATA_DIR", os.path.join(REPO, "..", "shared", "data"))
TEST_PYTHON = os.environ.get("SURFCAST_TEST_PYTHON", os.path.join(REPO, "build", "test-venv", "bin", "python"))
VENV = os.environ.get("SURFCAST_DASK_VENV", os.path.join(REPO, "build", "dask-venv"))

# A budget that cuts the built-in scene into several chunks (stages_test's),
# and a larger scene whose chunk tasks last long enough to be killed.
SCENE = ["--default-scene", "--scene-points", "300000", "--memory", "160M", "--capacity", "4000"]
LONGER = ["--default-scene", "--scene-points", "1000000", "--memory", "160M", "--capacity", "4000"]


def require_data(test):
    if not os.path.isdir(DATA):
        if os.environ.get("CI"):
            test.fail(f"no shared data at {DATA}")
        test.skipTest(f"no shared data at {DATA}")


def read(path):
    with open(path, "rb") as f:
        return f.read()


def same_set(a, b):
    return all(read(os.path.join(a, f)) == read(os.path.join(b, f)) for f in ("tileset.json", "hierarchy.bin", "blocks.bin"))


def one_process(options, out):
    r = subprocess.run([SURFCAST_BUILD, "-q"] + options + ["-o", out], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


class TokenHost:
    """A real HTTP server on loopback serving `root`'s files by Range, to
    requests that carry "Authorization: Bearer TOKEN" only (401 otherwise)."""

    def __init__(self, root, token):
        import http.server
        import threading

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def answer(self, body):
                path = os.path.join(root, os.path.basename(self.path.split("?")[0]))
                if self.headers.get("Authorization") != f"Bearer {token}" or not os.path.isfile(path):
                    self.send_response(401 if os.path.isfile(path) else 404)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                size = os.path.getsize(path)
                m = re.match(r"bytes=(\d+)-(\d*)$", self.headers.get("Range", ""))
                start, end = (int(m[1]), min(int(m[2]) if m[2] else size - 1, size - 1)) if m else (0, size - 1)
                self.send_response(206 if m else 200)
                if m:
                    self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
                self.send_header("Accept-Ranges", "bytes")
                self.send_header("Content-Length", str(end - start + 1))
                self.end_headers()
                if body:
                    with open(path, "rb") as f:
                        f.seek(start)
                        self.wfile.write(f.read(end - start + 1))

            def do_GET(self):
                self.answer(True)

            def do_HEAD(self):
                self.answer(False)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


def parent_of(pid):
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[1])


def stage_processes(stage, work):
    """PIDs of surfcast-build processes running `stage` on the work folder `work`
    (not those of other tests running beside this one)."""
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                argv = f.read().split(b"\0")
        except OSError:
            continue
        if len(argv) > 1 and argv[0].endswith(b"surfcast-build") and argv[1] == stage.encode() and work.encode() in argv:
            pids.append(int(entry))
    return pids


def wait_for(condition, seconds, what):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        found = condition()
        if found:
            return found
        time.sleep(0.02)
    raise AssertionError(f"{what}: not within {seconds} s")


class Cluster:
    """A scheduler and two single-threaded worker processes, each under a nanny.
    With `alone`, each worker starts in an empty folder of its own (its
    working and local directory) with the environment `env`: machines that
    share no path."""

    def __init__(self, tmp, env=None, alone=False):
        dask = os.path.join(VENV, "bin", "dask")
        self.file = os.path.join(tmp, "scheduler.json")
        quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self.procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                        "--scheduler-file", self.file], env=env, **quiet)]
        wait_for(lambda: os.path.exists(self.file), 60, "the scheduler's file")
        with open(self.file) as f:
            self.address = json.load(f)["address"]
        for i in range(2):
            own = os.path.join(tmp, f"worker-{i}") if alone else tmp
            os.makedirs(own, exist_ok=True)
            # Alone, its temporary files (the stages' copies of the work) go in its folder too.
            mine = dict(env or os.environ, TMPDIR=own) if alone else env
            self.procs.append(subprocess.Popen([dask, "worker", self.address, "--nthreads", "1", "--no-dashboard",
                                                "--local-directory", own], cwd=own, env=mine, **quiet))
        wait_for(lambda: self.workers() == 2, 60, "two workers")

    def workers(self):
        python = os.path.join(VENV, "bin", "python")
        r = subprocess.run([python, "-c", "import sys; from distributed import Client; "
                            "c = Client(sys.argv[1], timeout=10); print(len(c.scheduler_info()['workers'])); c.close()",
                            self.address], capture_output=True, text=True)
        return int(r.stdout.strip() or 0)

    def close(self):
        for p in self.procs:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for p in self.procs:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)


class DaskBuild(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        # The driver's pinned environment (made on first use).
        r = subprocess.run([DRIVER, "--help"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        cls.tmp = tempfile.mkdtemp(prefix="surfcast-dask-test-")
        cls.cluster = Cluster(cls.tmp)
        # lone-star.laz in over 1,000 small LAZ files, as an octree writer leaves it.
        cls.tiles = os.path.join(cls.tmp, "tiles")
        if os.path.isdir(DATA):
            split = subprocess.run([TEST_PYTHON, os.path.join(REPO, "tests", "tools", "split_laz.py"),
                                    os.path.join(DATA, "lone-star.laz"), cls.tiles, "--cells", "32x32x8",
                                    "--min-files", "1000"], capture_output=True, text=True)
            assert split.returncode == 0, split.stderr

    @classmethod
    def tearDownClass(cls):
        cls.cluster.close()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def setUp(self):
        self.dir = tempfile.mkdtemp(dir=self.tmp)

    def path(self, name):
        return os.path.join(self.dir, name)

    def driver(self, options, out, *extra):
        return [DRIVER, "--scheduler", self.cluster.address, "-q", *extra] + options + ["-o", out]

    def test_same_bytes_as_one_process_and_within_budget(self):
        require_data(self)
        # The built-in scene across chunks, lone-star.laz in over 1,000 LAZ
        # files, and one COPC file cut into three parts at its LAZ chunks.
        copc = [os.path.join(DATA, "lion_takanawa.copc.laz"), "--memory", "128M", "--capacity", "2000"]
        for name, options, budget, parts, cuts in (("scene", SCENE, 160 << 20, None, 0),
                                                   ("tiles", [self.tiles, "--memory", "128M", "--capacity", "4000"], 128 << 20, None, 0),
                                                   ("copc", copc, 128 << 20, 3, 2)):
            one_process(options, self.path(name + "-one"))
            report = self.path(name + ".json")
            extra = ["--report", report] + (["--parts", str(parts)] if parts else [])
            r = subprocess.run(self.driver(options, self.path(name + "-dask"), *extra), capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertTrue(same_set(self.path(name + "-one"), self.path(name + "-dask")), name)
            with open(report) as f:
                record = json.load(f)
            tasks = record["tasks"]
            # Parts that start within a file: the COPC file's two cuts.
            self.assertEqual(sum(p["begin"] > 0 for p in record["input_parts"]), cuts, name)
            chunks = [t for t in tasks if t["stage"] == "chunk"]
            self.assertGreaterEqual(len(chunks), 4, name)
            # Each stage's process within its budget + 10 % (out_of_core_test's bound).
            for t in tasks:
                self.assertLessEqual(t["rss"], budget * 1.1, f"{name}: {t}")
            self.assertFalse(os.path.exists(os.path.join(self.dir, "." + name + "-dask.dask-work")), "work folder left")

    def test_a_preview_and_versions_while_the_chunks_are_built(self):
        # --preview: the preview task beside the scan, a refine task once a
        # chunk is built (--preview-interval 0), and the set the one-process
        # bytes. A poll of -o sees the preview and a version with chunks
        # built, each a whole set.
        import threading

        out, report = self.path("set"), self.path("report.json")
        one_process(SCENE, self.path("one"))
        seen, broken, stop = [], [], threading.Event()

        def poll():
            while not stop.is_set():
                try:
                    text = read(os.path.join(out, "tileset.json"))
                    info = json.loads(text)
                    if info.get("preview") and info["preview"] not in seen:
                        seen.append(info["preview"])
                        verified = subprocess.run([SURFCAST_BUILD, "--info", out], capture_output=True, text=True)
                        if verified.returncode != 0 and read(os.path.join(out, "tileset.json")) == text:
                            broken.append(verified.stderr)  # (not a version replaced while verified)
                except (OSError, ValueError):
                    pass  # none yet, or replaced while read
                time.sleep(0.005)

        poller = threading.Thread(target=poll)
        poller.start()
        try:
            r = subprocess.run(self.driver(SCENE, out, "--preview", "--preview-points", "5000", "--preview-interval", "0",
                                           "--report", report), capture_output=True, text=True)
        finally:
            stop.set()
            poller.join()
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertTrue(same_set(self.path("one"), out))
        self.assertEqual(broken, [])
        with open(report) as f:
            stages = json.load(f)["stages"]
        self.assertEqual(stages["preview"]["tasks"], 1)
        self.assertGreaterEqual(stages["refine"]["tasks"], 1)
        self.assertTrue(any(p.get("done", 0) == 0 for p in seen), f"no preview seen: {seen}")
        self.assertTrue(any(0 < p.get("done", 0) < 1 for p in seen), f"no version with chunks built seen: {seen}")

    def test_worker_killed_mid_chunk(self):
        out, work = self.path("set"), self.path("work")
        one_process(LONGER, self.path("one"))
        driver = subprocess.Popen(self.driver(LONGER, out, "--work", work), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
        # SIGKILL the worker process (not its nanny) that runs the first chunk
        # task seen, while the task's surfcast-build is building it.
        chunk = wait_for(lambda: stage_processes("chunk", work), 120, "a chunk task")[0]
        worker = parent_of(chunk)
        self.assertIn(b"python", read(f"/proc/{worker}/cmdline"), "a chunk task's parent should be a worker process")
        os.kill(worker, signal.SIGKILL)
        stdout, stderr = driver.communicate(timeout=300)
        self.assertEqual(driver.returncode, 0, stderr)
        self.assertTrue(same_set(out, self.path("one")))
        wait_for(lambda: self.cluster.workers() == 2, 60, "the nanny's new worker")

    def test_driver_killed_and_started_again_resumes(self):
        out, work = self.path("set"), self.path("work")
        one_process(LONGER, self.path("one"))
        nodes = os.path.join(work, "nodes")
        driver = subprocess.Popen(self.driver(LONGER, out, "--work", work, "--keep-work"), stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        wait_for(lambda: os.path.isdir(nodes) and [n for n in os.listdir(nodes) if n.endswith(".nodes")], 120, "a finished chunk")
        driver.kill()
        driver.wait()
        # The tasks the driver had submitted may still finish (the scheduler
        # drops the queued ones once it sees the client gone); wait until the
        # finished chunks stay the same for three seconds.
        def finished():
            return sorted(n for n in os.listdir(nodes) if n.endswith(".nodes"))
        done, steady = finished(), time.monotonic()
        while time.monotonic() - steady < 3 or stage_processes("chunk", work):
            time.sleep(0.2)
            if finished() != done:
                done, steady = finished(), time.monotonic()
        self.assertFalse(os.path.exists(out), "a set appeared before the merge")
        # One finished chunk's record file cut short (a partial output): never used.
        cut = os.path.join(nodes, done[0])
        os.truncate(cut, os.path.getsize(cut) - 9)
        r = subprocess.run([DRIVER, "--scheduler", self.cluster.address, "--work", work, "--keep-work"] + LONGER + ["-o", out],
                           capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn(f"resuming: plan done, {len(done) - 1} of ", r.stderr)
        self.assertTrue(same_set(out, self.path("one")))

    def test_update_same_bytes_as_one_process(self):
        # An update through the driver (update-plan, chunk tasks, update-merge)
        # against surfcast-build's in one process, on a copy of the set at the
        # same path (the build record names it): every file the same bytes.
        # autzen_trim.las in 4 x 4 files (update_test's cells): r000005.laz
        # added to the others, then r000000.laz removed.
        require_data(self)
        parts = self.path("parts")
        split = subprocess.run([TEST_PYTHON, os.path.join(REPO, "tests", "tools", "split_laz.py"),
                                os.path.join(DATA, "autzen_trim.las"), parts, "--cells", "4x4x1", "--min-files", "16"],
                               capture_output=True, text=True)
        self.assertEqual(split.returncode, 0, split.stderr)
        added = os.path.join(parts, "r000005.laz")
        base = [os.path.join(parts, f) for f in sorted(os.listdir(parts)) if f != "r000005.laz"]
        out = self.path("set")
        one_process(base + ["--memory", "64M", "--capacity", "1000"], out)
        for i, update in enumerate((["--add", added], ["--remove", "r000000.laz"])):
            before = self.path(f"before-{i}")
            shutil.copytree(out, before)
            r = subprocess.run([SURFCAST_BUILD, "-q"] + update + ["--to", out], capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            expected = self.path(f"expected-{i}")
            os.rename(out, expected)
            shutil.copytree(before, out)
            report = self.path(f"update-{i}.json")
            r = subprocess.run([DRIVER, "--scheduler", self.cluster.address, "-q", "--report", report] + update + ["--to", out],
                               capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertEqual(sorted(os.listdir(out)), sorted(os.listdir(expected)), update)
            for f in os.listdir(out):
                self.assertEqual(read(os.path.join(out, f)), read(os.path.join(expected, f)), f"{update}: {f}")
            with open(report) as f:
                record = json.load(f)
            stages = [t["stage"] for t in record["tasks"]]
            self.assertEqual(stages[0], "update-plan")
            self.assertEqual(stages[-1], "update-merge")
            # Some chunks built again, as tasks, and some kept (surfcast-build
            # prints how many it built again: "; N chunks built again").
            built = int(re.search(r"(\d+) chunks built again", r.stdout).group(1))
            self.assertEqual(stages.count("chunk"), built, update)
            self.assertGreaterEqual(built, 2, update)
            self.assertLess(built, record["chunks"], update)
            self.assertFalse(os.path.exists(os.path.join(self.dir, ".set.dask-work")), "work folder left")
        # A driver started again on the work folder of an update it finished
        # (kept here; a driver killed after the switch leaves it too) finds
        # the set done, and changes nothing.
        update = ["--add", os.path.join(parts, "r000000.laz"), "--to", out]
        driver = [DRIVER, "--scheduler", self.cluster.address, "-q"] + update
        r = subprocess.run(driver + ["--keep-work"], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        files = {f: read(os.path.join(out, f)) for f in os.listdir(out)}
        r = subprocess.run(driver, capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn("holds this update already", r.stderr)
        self.assertEqual({f: read(os.path.join(out, f)) for f in os.listdir(out)}, files)

    def test_inputs_at_urls_are_reached_by_every_stage_and_never_stored(self):
        # A scan at a URL that wants a token: the stages that read it (scan,
        # count, plan and distribute) all take --header, which neither the
        # driver's record nor its report keeps.
        require_data(self)
        secret = "sEcReT-123"
        host = TokenHost(DATA, secret)
        try:
            options = [f"{host.url}/autzen_trim.las", "--header", f"Authorization: Bearer {secret}", "--capacity", "4000"]
            one_process(options, self.path("one"))
            report = self.path("report.json")
            r = subprocess.run(self.driver(options, self.path("dask"), "--parts", "2", "--keep-work", "--report", report),
                               capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertTrue(same_set(self.path("one"), self.path("dask")))
            for path in (report, os.path.join(self.dir, ".dask.dask-work", "driver.json")):
                self.assertNotIn(secret, read(path).decode(), path)
        finally:
            host.close()

    def test_bad_file_among_many_names_it_and_keeps_the_old_set(self):
        require_data(self)
        out = self.path("set")
        one_process(SCENE, out)
        old = read(os.path.join(out, "blocks.bin"))
        shutil.copytree(self.tiles, self.path("in"))
        files = sorted(os.listdir(self.path("in")))
        bad = files[len(files) // 2]
        laz = read(self.path("in/" + bad))
        with open(self.path("in/" + bad), "wb") as f:
            f.write(laz[:len(laz) * 7 // 10])  # cut at 70 %: its chunk table lies past its end
        r = subprocess.run(self.driver([self.path("in")], out), capture_output=True, text=True)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn(bad + ": LAZ: the chunk table offset", r.stderr)
        self.assertIn("file of", r.stderr)
        self.assertEqual(read(os.path.join(out, "blocks.bin")), old)


class WorkFileMagics(unittest.TestCase):
    def test_the_driver_reads_the_magics_the_builder_writes(self):
        # The driver tells finished work from the files' magics (its resume);
        # one it spells otherwise never matches, and that stage is always run again.
        sources = ""
        for name in ("plan_stage.cpp", "distribute_stage.cpp", "work_files.cpp", "update.cpp"):
            with open(os.path.join(REPO, "preprocess", "octree", name)) as f:
                sources += f.read()
        builder = dict(re.findall(r'constexpr char k(\w+)Magic\[9\] = "(\w{8})"', sources))
        driver = {}
        with open(DRIVER) as f:
            for names, values in re.findall(r"^((?:\w+_MAGIC, )*\w+_MAGIC) = ((?:b\"\w{8}\", )*b\"\w{8}\")$", f.read(), re.M):
                driver.update(zip(names.split(", "), re.findall(r'b"(\w{8})"', values)))
        expected = {"SCAN_MAGIC": "Scan", "COUNT_MAGIC": "Count", "PLAN_MAGIC": "Plan", "DISTRIBUTION_MAGIC": "Distribution",
                    "NODES_MAGIC": "Chunk", "UPDATE_MAGIC": "Update"}
        self.assertEqual(set(driver), set(expected))
        for name, cpp in expected.items():
            self.assertEqual(driver[name], builder[cpp], name)


class ShareNothing(unittest.TestCase):
    """Workers that share nothing but an S3 store (SeaweedFS, tests/tools/seaweedfs.py):
    each starts in an empty folder of its own, and every input, work file and
    the set live in the store (--work s3://...)."""

    @classmethod
    def setUpClass(cls):
        r = subprocess.run([DRIVER, "--help"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        cls.tmp = tempfile.mkdtemp(prefix="surfcast-dask-store-test-")
        sys.path.insert(0, os.path.join(REPO, "tests", "tools"))
        from seaweedfs import SeaweedFs
        os.makedirs(os.path.join(cls.tmp, "store"))
        cls.store = SeaweedFs(os.path.join(cls.tmp, "store"), 18533, "surfcast")
        cls.env = dict(os.environ, **cls.store.environment())
        os.makedirs(os.path.join(cls.tmp, "cluster"))
        cls.cluster = Cluster(os.path.join(cls.tmp, "cluster"), cls.env, alone=True)

    @classmethod
    def tearDownClass(cls):
        cls.cluster.close()
        cls.store.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def setUp(self):
        self.dir = tempfile.mkdtemp(dir=self.tmp)

    def same_as(self, folder, prefix):
        return all(self.store.get(f"{prefix}/{f}") == read(os.path.join(folder, f)) for f in ("tileset.json", "hierarchy.bin", "blocks.bin"))

    def driver(self, options, out, *extra):
        # The driver runs in a folder of its own too.
        return subprocess.run([DRIVER, "--scheduler", self.cluster.address, *extra] + options + ["-o", out],
                              capture_output=True, text=True, env=self.env, cwd=self.dir)

    def test_same_bytes_as_one_process(self):
        require_data(self)
        # A COPC file in the bucket, cut into three parts at its LAZ chunks.
        copc = os.path.join(DATA, "lion_takanawa.copc.laz")
        self.store.put("in/lion_takanawa.copc.laz", copc)
        options = ["--memory", "128M", "--capacity", "2000"]
        one_process([copc] + options, os.path.join(self.dir, "one"))
        r = self.driver(["s3://surfcast/in/lion_takanawa.copc.laz"] + options, "s3://surfcast/sets/copc",
                        "--work", "s3://surfcast/work/copc", "--parts", "3")
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertTrue(self.same_as(os.path.join(self.dir, "one"), "sets/copc"))
        self.assertEqual(self.store.keys("work/copc/"), [], "work files left in the store")
        for worker in ("worker-0", "worker-1"):
            left = [f for f in os.listdir(os.path.join(self.tmp, "cluster", worker)) if not f.startswith("dask-scratch")]
            self.assertEqual(left, [], f"{worker} kept files of its own: {left}")

    def test_worker_killed_mid_chunk_and_driver_started_again(self):
        one_process(LONGER, os.path.join(self.dir, "one"))
        work = "s3://surfcast/work/longer"
        driver = subprocess.Popen([DRIVER, "--scheduler", self.cluster.address, "-q", "--work", work, "--keep-work"] + LONGER +
                                  ["-o", "s3://surfcast/sets/longer"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  env=self.env, cwd=self.dir)
        # SIGKILL the worker process that runs the first chunk task seen.
        chunk = wait_for(lambda: stage_processes("chunk", work), 120, "a chunk task")[0]
        os.kill(parent_of(chunk), signal.SIGKILL)
        # Then the driver, once a chunk's output is in the store.
        wait_for(lambda: [k for k in self.store.keys("work/longer/nodes/") if k.endswith(".nodes")], 120, "a finished chunk")
        driver.kill()
        driver.wait()
        wait_for(lambda: not stage_processes("chunk", work), 120, "the chunk tasks to end")
        wait_for(lambda: self.cluster.workers() == 2, 60, "the nanny's new worker")
        self.assertIsNone(self.store.get("sets/longer/tileset.json"), "a set appeared before the merge")
        # Started again from another folder (the work in a store holds no path).
        elsewhere = os.path.join(self.dir, "elsewhere")
        os.makedirs(elsewhere)
        r = subprocess.run([DRIVER, "--scheduler", self.cluster.address, "--work", work] + LONGER + ["-o", "s3://surfcast/sets/longer"],
                           capture_output=True, text=True, env=self.env, cwd=elsewhere)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn("resuming: plan done", r.stderr)
        self.assertTrue(self.same_as(os.path.join(self.dir, "one"), "sets/longer"))


if __name__ == "__main__":
    unittest.main(verbosity=2)
