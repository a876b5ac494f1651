#!/usr/bin/env python3
"""Which product lines and branches each test case of the ASan stage runs, and
which slow cases run nothing the stage's other cases do not.

  cmake --preset asan-coverage && cmake --build build-asan-coverage --parallel
  bench/case_coverage.py run [--build build-asan-coverage] [--out DIR] [-R REGEX]
  bench/case_coverage.py report [--out DIR] [--min-seconds S] [--keep REGEX]

`run` runs each case of every test program alone (ctest's command, filter,
working folder and environment, and scripts/sanitize.sh's sanitizer options),
two programs at a time as the stage does, with each process's profile under
LLVM_PROFILE_FILE (the programs a case starts write theirs too). The
asan-coverage preset runs the cases SURFCAST_SKIP_address_covered leaves out
of the ASan stage, so that they are measured again. It keeps, per case, its
seconds and the set of lines and branch directions it ran in the product's
sources (common/ net/ preprocess/ export/ server/ client/), not the tests'
own code. `report` then drops the slowest cases first, each only while every
line and branch direction it runs is run by a case still kept, and compares
its choice with tests/CMakeLists.txt's list. The decision and its numbers:
bench/RELIABILITY.md, "What each CI stage covers".

Line coverage says which code ran under the sanitizer, not with which data: a
case whose lines another case runs can still be the only one with its sizes.
A killed process writes no profile, so a case that failed, or whose
processes left none or no product line, is never dropped. A passing case
that kills only some of its processes shows part of what it ran, unseen: the
cases that SIGKILL their builds (`KillAnywhere...`, `BadInput.*`) are kept by
--keep's default.
"""
import argparse
import concurrent.futures
import functools
import json
import os
import pathlib
import re
import shutil
import signal
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
PRODUCT = ("common/", "net/", "preprocess/", "export/", "server/", "client/")
# The programs a test may start, beside the test program itself.
PROGRAMS = ("surfcast-build", "surfcast-view", "surfcast-serve", "surfcast-export", "surfcast-weights",
            "surfcast-mesh-reference")
# Cases kept whatever they share: their inputs (bad input) and their timing
# (the server's clients) are the point, and lines do not show them; and the
# cases that SIGKILL their builds, whose profiles are lost.
KEEP = r"^(BadInput|ServerTest)\.|\.KillAnywhere"
# scripts/sanitize.sh's options for the ASan stage.
SANITIZER_ENV = {"UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1",
                 "ASAN_OPTIONS": "detect_leaks=1:strict_string_checks=1", "OMP_WAIT_POLICY": "passive"}


@functools.lru_cache(maxsize=None)
def llvm_tool(name):
    """llvm-cov or llvm-profdata of the clang that builds the preset (their profile formats must match)."""
    major = subprocess.run(["clang++", "-dumpversion"], check=True, capture_output=True, text=True).stdout.split(".")[0]
    tool = shutil.which(f"{name}-{major}")
    if not tool:
        sys.exit(f"case_coverage: {name}-{major} not found (Debian: apt-get install llvm-{major})")
    return tool


def ctest_tests(build):
    out = subprocess.run(["ctest", "--test-dir", str(build), "--show-only=json-v1"], check=True,
                         capture_output=True, text=True).stdout
    tests = []
    for t in json.loads(out)["tests"]:
        props = {p["name"]: p["value"] for p in t.get("properties", [])}
        if not t.get("command"):
            sys.exit(f"case_coverage: ctest names no command for {t['name']}: build {build} first")
        env = dict(e.split("=", 1) for e in props.get("ENVIRONMENT", []))
        tests.append({"name": t["name"], "command": t["command"], "env": env,
                      "cwd": props.get("WORKING_DIRECTORY", str(build))})
    return tests


def list_cases(test):
    """The cases ctest's command runs (its own --gtest_filter applies)."""
    out = subprocess.run(test["command"] + ["--gtest_list_tests"], check=True, capture_output=True, text=True,
                         cwd=test["cwd"], env={**os.environ, **SANITIZER_ENV, "LLVM_PROFILE_FILE": os.devnull}).stdout
    cases, suite = [], None
    for line in out.splitlines():
        if not line.strip():
            continue
        if not line.startswith(" "):
            suite = line.split("#")[0].strip()
        else:
            cases.append(suite + line.split("#")[0].strip())
    return cases


def covered(profdata, objects):
    """(file:line) and (file:line:block:branch) items the profile ran, product sources only."""
    args = [llvm_tool("llvm-cov"), "export", "-format=lcov", "-instr-profile", str(profdata), str(objects[0])]
    for o in objects[1:]:
        args += ["-object", str(o)]
    return product_items(subprocess.run(args, check=True, capture_output=True, text=True).stdout)


def product_items(lcov):
    """The lines (file:line) and branch directions (file:line:block:branch) an
    LCOV text counts as run, in the product's sources only."""
    items, path = set(), None
    for line in lcov.splitlines():
        if line.startswith("SF:"):
            rel = os.path.relpath(line[3:], ROOT)
            path = rel if rel.startswith(PRODUCT) else None
        elif path is None:
            continue
        elif line.startswith("DA:"):
            number, count = line[3:].split(",")[:2]
            if int(count) > 0:
                items.add(f"{path}:{number}")
        elif line.startswith("BRDA:"):
            number, block, branch, taken = line[5:].split(",")
            if taken not in ("-", "0"):
                items.add(f"{path}:{number}:{block}:{branch}")
    return items


def run_program(test, cases, build, out):
    bin_dir = build / "bin"
    objects = [pathlib.Path(test["command"][0])] + [bin_dir / p for p in PROGRAMS if (bin_dir / p).exists()]
    (out / "cases").mkdir(exist_ok=True)
    (out / "profdata").mkdir(exist_ok=True)
    results = {}
    for case in cases:
        raw = out / "raw" / case
        shutil.rmtree(raw, ignore_errors=True)
        raw.mkdir(parents=True)
        command = [a for a in test["command"] if not a.startswith("--gtest_filter=")] + [f"--gtest_filter={case}"]
        env = {**os.environ, **SANITIZER_ENV, **test["env"], "LLVM_PROFILE_FILE": str(raw / "%p-%m.profraw")}
        start = time.monotonic()
        # A session of its own, so that a timeout (scripts/sanitize.sh's ctest
        # one) stops the servers and windows the case started too.
        proc = subprocess.Popen(command, cwd=test["cwd"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)
        try:
            log = proc.communicate(timeout=3600)[0]
            status = proc.returncode
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            log = proc.communicate()[0] + "\ncase_coverage: timed out after 3600 s"
            status = "timeout"
        seconds = time.monotonic() - start
        profiles = sorted(raw.glob("*.profraw"))
        items = set()
        if profiles:
            profdata = out / "profdata" / f"{case}.profdata"
            merged = subprocess.run([llvm_tool("llvm-profdata"), "merge", "-sparse", "-o", str(profdata)] +
                                    [str(p) for p in profiles], capture_output=True, text=True)
            if merged.returncode == 0:
                items = covered(profdata, objects)
            else:  # a damaged profile: the case counts as unmeasured
                status, log = "unreadable profile", log + merged.stderr
        shutil.rmtree(raw)
        results[case] = {"test": test["name"], "seconds": round(seconds, 2), "exit": status,
                         "processes": len(profiles), "items": sorted(items)}
        print(f"{seconds:7.1f} s {len(items):6d} items {len(profiles):3d} processes  {case}  "
              f"{'ok' if status == 0 else f'EXIT {status}'}", flush=True)
        if status != 0:
            (out / f"{case}.log").write_text(log)
        # Written after each case, so that an interrupted run keeps what it measured.
        (out / "cases" / f"{test['name']}.json").write_text(json.dumps(results))
    return results


def run(args):
    build, out = pathlib.Path(args.build).resolve(), pathlib.Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    llvm_tool("llvm-cov"), llvm_tool("llvm-profdata")  # a missing tool is an error now, not after a case
    tests = [t for t in ctest_tests(build) if re.search(args.R, t["name"])]
    work = [(t, list_cases(t)) for t in tests]
    # Longest programs first (most cases first: a stand-in for their cost).
    work.sort(key=lambda w: -len(w[1]))
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        for f in [pool.submit(run_program, t, cases, build, out) for t, cases in work]:
            f.result()


def cmake_list():
    """The cases tests/CMakeLists.txt leaves out of ASan by this report (SURFCAST_SKIP_address_covered)."""
    text = (ROOT / "tests" / "CMakeLists.txt").read_text()
    body = re.search(r"set\(SURFCAST_SKIP_address_covered\n(.*?)\)", text, re.S)
    return [w for line in body.group(1).splitlines() for w in line.split("#")[0].split()] if body else []


def choose(cases, min_seconds, keep):
    """The cases to leave out, slowest first, each only while every item it
    runs is run by a case still kept; cases matching `keep`, faster than
    `min_seconds`, or whose measurement is incomplete (a failure, no profile)
    are kept. Prints why each slow case is kept."""
    counts = {}
    for r in cases.values():
        for item in r["items"]:
            counts[item] = counts.get(item, 0) + 1
    dropped = []
    for case, r in sorted(cases.items(), key=lambda kv: (-kv[1]["seconds"], kv[0])):
        if r["seconds"] < min_seconds or re.search(keep, case):
            continue
        if r["exit"] != 0 or r["processes"] == 0 or not r["items"]:
            print(f"  keep {case} ({r['seconds']:.1f} s): its measurement is incomplete "
                  f"(exit {r['exit']}, {r['processes']} profiles, {len(r['items'])} items)")
            continue
        unique = [i for i in r["items"] if counts[i] == 1]
        if unique:
            lines = sorted({":".join(i.split(":")[:2]) for i in unique})
            print(f"  keep {case} ({r['seconds']:.1f} s): {len(unique)} items only it runs, e.g. {', '.join(lines[:4])}")
            continue
        for i in r["items"]:
            counts[i] -= 1
        dropped.append(case)
    return dropped


def report(args):
    out = pathlib.Path(args.out)
    cases = {}
    for f in sorted((out / "cases").glob("*.json")):
        cases.update(json.loads(f.read_text()))
    if not cases:
        sys.exit(f"case_coverage: no measured cases in {out / 'cases'}: run `bench/case_coverage.py run` first")
    items = set().union(*(r["items"] for r in cases.values()))
    total = sum(r["seconds"] for r in cases.values())
    print(f"{len(cases)} cases, {total:.0f} s alone, {len(items)} product lines and branch directions run")
    dropped = choose(cases, args.min_seconds, args.keep)
    saved = sum(cases[c]["seconds"] for c in dropped)
    print(f"dropped {len(dropped)} cases, {saved:.0f} s of {total:.0f} s alone, every item still run:")
    for c in dropped:
        print(f"  {c} ({cases[c]['test']}, {cases[c]['seconds']:.1f} s)")
    listed = cmake_list()
    unmeasured = [c for c in listed if c not in cases]
    if unmeasured:
        print("SURFCAST_SKIP_address_covered names cases this run did not measure (configure with the "
              "asan-coverage preset):", ", ".join(unmeasured))
    for name, which in (("chosen now, not in SURFCAST_SKIP_address_covered", set(dropped) - set(listed)),
                        ("in SURFCAST_SKIP_address_covered, not chosen now", (set(listed) & set(cases)) - set(dropped))):
        if which:
            print(f"{name}: {', '.join(sorted(which))}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run each case alone and keep what it covers")
    r.add_argument("--build", default=str(ROOT / "build-asan-coverage"))
    r.add_argument("--out", default=str(ROOT / "build-asan-coverage" / "case-coverage"))
    r.add_argument("--jobs", type=int, default=2)
    r.add_argument("-R", default="", help="only the ctest tests whose names match")
    p = sub.add_parser("report", help="the slow cases whose lines other cases run")
    p.add_argument("--out", default=str(ROOT / "build-asan-coverage" / "case-coverage"))
    p.add_argument("--min-seconds", type=float, default=3.0, help="consider dropping only cases this slow")
    p.add_argument("--keep", default=KEEP, help=f"a regex of cases kept whatever other cases run (default {KEEP})")
    args = parser.parse_args()
    run(args) if args.command == "run" else report(args)


if __name__ == "__main__":
    main()
