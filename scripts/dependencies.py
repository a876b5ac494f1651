#!/usr/bin/env python3
"""Writes docs/DEPENDENCIES.md: every dependency of Surfcast with its version, its
licence and why that licence allows distributing Surfcast under Apache-2.0. Sources:
the Debian packages of scripts/setup.sh (licences from /usr/share/doc/PKG/copyright),
the crates of preprocess/readers/laz_ffi/Cargo.lock (from cargo's registry sources),
the direct npm packages of web/package.json, and the tools built outside those.
Standard library only, offline; a package not installed here keeps its licence from
DEBIAN below and its version reads "not installed here".
Usage: scripts/dependencies.py [--check]
  --check  regenerate in memory and compare with docs/DEPENDENCIES.md, the version
           column aside (Debian point releases change it); exit 1 on a difference,
           or on a licence outside the allowlist of its role (ALLOWED)."""
import difflib, json, os, re, shutil, subprocess, sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "DEPENDENCIES.md"
MISSING = "not installed here"

# The licences each role may carry (SPDX; an "A OR B" passes when one side does).
# Code in the programs or the browser bundle: permissive, or MPL-2.0 (file-level
# copyleft: unmodified MPL files may sit in an Apache-2.0 program), or the GCC
# runtime exception. Dynamically linked system libraries may also be LGPL: the user
# can replace them. Tools and test-only programs are not distributed with Surfcast.
PERMISSIVE = {"Apache-2.0", "MIT", "BSD-2-Clause", "BSD-3-Clause", "ISC", "Zlib", "curl", "BSL-1.0",
              "Unlicense", "public-domain", "Apache-2.0 WITH LLVM-exception"}
SHIPPED = PERMISSIVE | {"MPL-2.0", "GPL-3.0-or-later WITH GCC-exception-3.1"}
LINKED = SHIPPED | {"LGPL-2.1-or-later", "LGPL-2.1-only", "LGPL-3.0-or-later"}
NOT_SHIPPED = LINKED | {"GPL-2.0-only", "GPL-2.0-or-later", "GPL-3.0-or-later", "Artistic-2.0", "PSF-2.0"}
ALLOWED = {"compiled in": SHIPPED, "bundled": SHIPPED, "linked": LINKED, "runtime": NOT_SHIPPED,
           "build tool": NOT_SHIPPED, "build script": NOT_SHIPPED, "test only": NOT_SHIPPED,
           "benchmark only": NOT_SHIPPED}
WHY = {"compiled in": "permissive: compatible; its notice goes with binaries",
       "bundled": "permissive: compatible; shipped in the viewer's files with its notice",
       "linked": "Debian's shared library, linked dynamically: compatible",
       "runtime": "loaded at run time from the user's system, not linked or shipped: fine",
       "build tool": "a build tool, not linked or shipped: not part of the product, fine",
       "build script": "runs only in a crate's build script, not compiled into the library: fine",
       "test only": "used by the tests only, not shipped: fine",
       "benchmark only": "a benchmark's comparison, not built into or shipped with Surfcast: fine",
       # By licence, where the role's reason is not enough.
       "LGPL": "LGPL, linked dynamically to Debian's unmodified library, which users can replace: "
               "compatible as used (static linking or changing it would add obligations)",
       "MPL": "MPL-2.0 is per file: the unmodified headers stay MPL-2.0 and Surfcast's code Apache-2.0: compatible"}

# Debian package: (upstream project, role, licence when its copyright file has no
# DEP-5 "Files: *" paragraph or is absent, note). A DEP-5 licence must agree.
DEBIAN = {
    "build-essential": ("GCC, make, libc headers", "build tool", "GPL-2.0-or-later", "the runtimes it links are libc6 and libstdc++6"),
    "cmake": ("CMake", "build tool", "BSD-3-Clause", ""),
    "ninja-build": ("Ninja", "build tool", "Apache-2.0", ""),
    "pkg-config": ("pkgconf", "build tool", "ISC", ""),
    "git": ("Git", "build tool", "GPL-2.0-only", ""),
    "zlib1g-dev": ("zlib", "linked", "Zlib", ""),
    "libcli11-dev": ("CLI11", "compiled in", "BSD-3-Clause", "header-only"),
    "libdraco-dev": ("Draco", "linked", "Apache-2.0", ""),
    "libopenmesh-dev": ("OpenMesh", "linked", "BSD-3-Clause", ""),
    "libflann-dev": ("FLANN", "linked", "BSD-3-Clause", ""),
    "liblz4-dev": ("LZ4", "linked", "BSD-2-Clause", "LZ4's GPL command-line programs are not used"),
    "libeigen3-dev": ("Eigen", "compiled in", "MPL-2.0", "header-only"),
    "libmeshoptimizer-dev": ("meshoptimizer", "linked", "MIT", ""),
    "libglfw3-dev": ("GLFW", "linked", "Zlib", ""),
    "libvulkan-dev": ("Vulkan loader and headers", "linked", "Apache-2.0", ""),
    "mesa-vulkan-drivers": ("Mesa", "runtime", "MIT", "a Vulkan driver the loader finds"),
    "vulkan-validationlayers": ("Vulkan validation layers", "test only", "Apache-2.0", "SURFCAST_VALIDATION=1"),
    "glslang-tools": ("glslang", "build tool", "BSD-3-Clause", "compiles the shaders; its output is not under its licence"),
    "libmicrohttpd-dev": ("GNU libmicrohttpd", "linked", "LGPL-2.1-or-later", "surfcast-serve's HTTP server"),
    "libcurl4-openssl-dev": ("libcurl", "linked", "curl", "MIT-style; it links OpenSSL 3 (Apache-2.0)"),
    "nlohmann-json3-dev": ("nlohmann/json", "compiled in", "MIT", "header-only"),
    "libstb-dev": ("stb", "linked", "public-domain OR MIT", ""),
    "curl": ("curl", "build tool", "curl", "scripts/demo.sh's downloads"),
    "python3": ("Python", "build tool", "PSF-2.0", "runs the scripts, benchmarks and Python tests"),
    "libcpp-httplib-dev": ("cpp-httplib", "test only", "MIT", "header-only, in test programs"),
    "libgtest-dev": ("GoogleTest", "test only", "BSD-3-Clause", ""),
    "python3-venv": ("Python venv", "test only", "PSF-2.0", ""),
    "xvfb": ("X.Org Xvfb", "test only", "MIT", ""),
    "xdotool": ("xdotool", "test only", "BSD-3-Clause", ""),
    "nginx-light": ("nginx", "test only", "BSD-2-Clause", "the web tests' and benchmarks' static server"),
    "chromium": ("Chromium", "test only", "BSD-3-Clause", "the web tests' headless browser"),
    "nodejs": ("Node.js", "build tool", "MIT", "runs the viewer's build and the web tests"),
    "npm": ("npm", "build tool", "Artistic-2.0", "installs the viewer's npm packages"),
    "cargo-web": ("Cargo", "build tool", "MIT OR Apache-2.0", ""),
    "rustc-web": ("Rust compiler and standard library", "compiled in", "MIT OR Apache-2.0",
                  "the standard library is compiled into the LAZ and E57 readers"),
    "clang": ("Clang", "build tool", "Apache-2.0 WITH LLVM-exception", "the sanitizer presets (setup.sh --clang)"),
    "libclang-rt-14-dev": ("LLVM compiler-rt", "test only", "Apache-2.0 WITH LLVM-exception", "sanitizer runtimes"),
    "libomp-14-dev": ("LLVM OpenMP", "test only", "Apache-2.0 WITH LLVM-exception", "the sanitizer builds' OpenMP"),
    # Not named by setup.sh: the toolchain's runtimes, which every program links.
    "libc6": ("GNU C Library", "linked", "LGPL-2.1-or-later", ""),
    "libstdc++6": ("GCC runtime (libstdc++, libgcc, libgomp)", "linked", "GPL-3.0-or-later WITH GCC-exception-3.1",
                   "the runtime library exception allows any licence for programs GCC compiles"),
}
TOOLCHAIN_RUNTIMES = ("libc6", "libstdc++6")
# Debian copyright "License:" names, as SPDX.
SPDX = {"apache-2": "Apache-2.0", "apache-2.0": "Apache-2.0", "expat": "MIT", "mit": "MIT",
        "bsd-3-clause": "BSD-3-Clause", "bsd-3clause": "BSD-3-Clause", "bsd-c3": "BSD-3-Clause",
        "bsd-2-clause": "BSD-2-Clause", "mpl-2": "MPL-2.0", "mpl-2.0": "MPL-2.0", "zlib": "Zlib", "isc": "ISC",
        "lgpl-2.1+": "LGPL-2.1-or-later", "gpl-2": "GPL-2.0-only", "gpl-2+": "GPL-2.0-or-later", "curl": "curl",
        "public-domain": "public-domain", "artistic-2.0": "Artistic-2.0",
        "apache-2-llvm-exceptions": "Apache-2.0 WITH LLVM-exception"}
NPM_BUNDLED = {"three": "the three.js layer's peer, copied beside the viewer",
               "draco3d": "its WASM decoder runs in the viewer's decode worker"}
NPM_BUILD = {"esbuild", "typescript", "@types/three"}

problems = []


def setup_packages():
    """The packages scripts/setup.sh can install: its packages and test_packages
    arrays and every packages+=(...) it adds on a condition or an option."""
    text = (ROOT / "scripts" / "setup.sh").read_text()
    names = []
    for body in re.findall(r"\b(?:test_)?packages\+?=\(([^)]*)\)", text):
        names += [w for w in body.split() if re.fullmatch(r"[a-z0-9][a-z0-9+.-]+", w)]
    return list(dict.fromkeys(names))


def dpkg_version(pkg):
    if not shutil.which("dpkg-query"):
        return MISSING
    r = subprocess.run(["dpkg-query", "-W", "-f=${db:Status-Status} ${Version}", pkg],
                       capture_output=True, text=True)
    status, _, version = r.stdout.partition(" ")
    return version if r.returncode == 0 and status == "installed" else MISSING


def copyright_licence(pkg):
    """The licence of a DEP-5 copyright file's "Files: *" paragraph, as SPDX; None
    when the file is absent or not DEP-5."""
    path = Path("/usr/share/doc") / pkg / "copyright"
    text = path.read_text(errors="replace") if path.is_file() else ""
    if not re.match(r"Format:", text):
        return None
    for para in re.split(r"\n\s*\n", text):
        if re.search(r"^Files:\s*\*\s*$", para, re.M):
            m = re.search(r"^License:\s*(\S.*)$", para, re.M)
            if m:
                words = re.split(r"\s+(or|and)\s+", m.group(1).strip(), flags=re.I)
                return " ".join(w.upper() if w.lower() in ("or", "and") else SPDX.get(w.lower(), w) for w in words)
    return None


def debian_rows():
    listed = setup_packages()
    for pkg in sorted(set(listed) - set(DEBIAN)):
        problems.append(f"{pkg}: scripts/setup.sh installs it but scripts/dependencies.py's DEBIAN has no entry")
    for pkg in sorted(set(DEBIAN) - set(listed) - set(TOOLCHAIN_RUNTIMES)):
        problems.append(f"{pkg}: in DEBIAN but scripts/setup.sh no longer installs it")
    rows = []
    for pkg in [p for p in listed if p in DEBIAN] + list(TOOLCHAIN_RUNTIMES):
        upstream, role, licence, note = DEBIAN[pkg]
        found = copyright_licence(pkg)
        if found and found != licence:
            problems.append(f"{pkg}: /usr/share/doc/{pkg}/copyright says {found}, DEBIAN says {licence}: review it")
            licence = found
        rows.append((pkg, upstream, dpkg_version(pkg), licence, role, note))
    return rows


def crate_rows():
    """Every crate of Cargo.lock. Edges come from the lock; one a crate's registry
    Cargo.toml lists only under [build-dependencies] is not followed, so what the
    root does not reach otherwise runs in build scripts only."""
    ffi = ROOT / "preprocess" / "readers" / "laz_ffi"
    lock = (ffi / "Cargo.lock").read_text()
    crates, root = {}, None
    for block in lock.split("[[package]]")[1:]:
        name = re.search(r'^name = "([^"]+)"', block, re.M).group(1)
        deps = re.search(r"^dependencies = \[(.*?)\]", block, re.M | re.S)
        crates[name] = {"version": re.search(r'^version = "([^"]+)"', block, re.M).group(1),
                        "deps": [d.split()[0] for d in re.findall(r'"([^"]+)"', deps.group(1))] if deps else []}
        if "source =" not in block:
            root = name
    home = Path(os.environ.get("CARGO_HOME", Path.home() / ".cargo"))
    for name, c in crates.items():
        if name == root:
            c["licence"], c["build_only"] = license_of(ffi / "Cargo.toml"), set()
            continue
        tomls = sorted(home.glob(f"registry/src/*/{name}-{c['version']}/Cargo.toml"))
        text = tomls[0].read_text() if tomls else ""
        c["licence"] = license_of(tomls[0]) if tomls else "unknown: not in cargo's registry (cargo fetch)"
        kinds = re.findall(r"^\[(?:target\.[^\]]+?\.)?(dependencies|build-dependencies)\.([\w-]+)\]", text, re.M)
        c["build_only"] = {d for k, d in kinds if k == "build-dependencies"} - {d for k, d in kinds if k == "dependencies"}
    reached, todo = set(), [root]
    while todo:
        name = todo.pop()
        if name not in reached:
            reached.add(name)
            todo += [d for d in crates[name]["deps"] if d not in crates[name]["build_only"]]
    if crates[root]["licence"] != "Apache-2.0":
        problems.append(f"{root}: preprocess/readers/laz_ffi/Cargo.toml's license is not Apache-2.0")
    users = {n: sorted(p for p, c in crates.items() if n in c["deps"]) for n in crates}
    return [(n, ", ".join(users[n]) or "-", c["version"], c["licence"],
             "compiled in" if n in reached else "build script", "")
            for n, c in sorted(crates.items()) if n != root]


def license_of(cargo_toml):
    m = re.search(r'^license\s*=\s*"([^"]+)"', Path(cargo_toml).read_text(), re.M)
    return m.group(1).replace("/", " OR ") if m else "unknown: no license field"


def npm_rows():
    web = ROOT / "web"
    pkg = json.loads((web / "package.json").read_text())
    lock = json.loads((web / "package-lock.json").read_text())["packages"]
    if pkg.get("license") != "Apache-2.0":
        problems.append("web/package.json's license is not Apache-2.0")
    rows = []
    for group in ("dependencies", "devDependencies"):
        for name in sorted(pkg.get(group, {})):
            entry = lock.get(f"node_modules/{name}", {})
            installed = web / "node_modules" / name / "package.json"
            licence = entry.get("license") or (json.loads(installed.read_text()).get("license")
                                               if installed.is_file() else None) or "unknown"
            role = "bundled" if name in NPM_BUNDLED else "build tool" if name in NPM_BUILD else "test only"
            if name in NPM_BUNDLED and entry.get("dependencies"):
                problems.append(f"{name}: bundled, but its own dependencies are not listed here")
            rows.append((name, group, entry.get("version", pkg[group][name]), licence, role, NPM_BUNDLED.get(name, "")))
    return rows


def other_rows():
    script = (ROOT / "scripts" / "install-seaweedfs.sh").read_text()
    weed = re.search(r"^version=(\S+)", script, re.M).group(1)
    go = shutil.which("go") or (shutil.which("go", path="/usr/local/go/bin"))
    go_version = subprocess.run([go, "env", "GOVERSION"], capture_output=True, text=True).stdout.strip() if go else ""
    return [("SeaweedFS", "scripts/install-seaweedfs.sh", weed, "Apache-2.0", "test only",
             "the object-store tests' S3 server, with the Go modules it is built from"),
            ("Go", "scripts/install-seaweedfs.sh", go_version or MISSING, "BSD-3-Clause", "test only", "builds SeaweedFS"),
            ("PotreeConverter", "bench/build_bench.py", "2", "BSD-2-Clause", "benchmark only",
             "built from ../shared/anchors, outside this repository")]


def allowed(licence, role):
    return any(all(part.strip("() ") in ALLOWED[role] for part in alt.split(" AND "))
               for alt in licence.split(" OR "))


def table(title, source, header, rows):
    out = [f"## {title}", "", source, "", f"| {' | '.join(header)} | Licence | Role | Compatible with distributing Surfcast under Apache-2.0 |",
           "|" + " --- |" * (len(header) + 3)]
    for name, where, version, licence, role, note in rows:
        kind = next((k for k in ("LGPL", "MPL") if k in licence and role in ("linked", "compiled in")), role)
        why = "; ".join(filter(None, [WHY[kind], note]))
        if not allowed(licence, role):
            problems.append(f"{name}: licence {licence} is not in the allowlist for the role '{role}'")
            why = f"NOT in the allowlist for a {role} dependency: review before distributing"
        out.append(f"| {name} | {where} | {version} | {licence} | {role} | {why} |")
    return out + [""]


def generate():
    lines = ["# Dependencies and their licences", "",
             "Surfcast is licensed under the Apache License 2.0 (`LICENSE`). This file lists what it builds",
             "with, links, ships and tests with, and why each licence allows that distribution. Generated by",
             "`scripts/dependencies.py`; `scripts/dependencies.py --check` (the test dependencies_test)",
             "compares it with the sources, versions aside, and fails on a licence outside its role's allowlist.",
             "", "Roles: *compiled in* (code or headers in Surfcast's programs and libraries), *linked* (a",
             "system shared library, linked dynamically and not shipped), *bundled* (in the browser viewer's",
             "files), *runtime* (loaded from the user's system), *build tool*, *build script*, *test only* and",
             "*benchmark only* (not part of what is distributed). Debian's shared libraries bring their own",
             "dependencies (e.g. OpenSSL under libcurl, GnuTLS under libmicrohttpd), loaded from the system.",
             "The Python packages pip installs into virtual environments for scripts/surfcast-dask",
             "(scripts/dask-requirements.txt) and the tests (tests/requirements.txt) are not listed.", ""]
    lines += table("Debian packages", "From scripts/setup.sh, with the toolchain runtimes every program links; "
                   "licences from `/usr/share/doc/PKG/copyright`.", ["Package", "Upstream", "Version"], debian_rows())
    lines += table("Rust crates", "Every crate of `preprocess/readers/laz_ffi/Cargo.lock`: compiled into the static "
                   "library libsurfcast_laz.a, or run by a build script.", ["Crate", "Used by", "Version"], crate_rows())
    lines += table("npm packages", "The direct dependencies of `web/package.json`; only the bundled ones reach a browser.",
                   ["Package", "Group", "Version"], npm_rows())
    lines += table("Other", "Built or fetched outside the package managers above.", ["Name", "Used by", "Version"],
                   other_rows())
    return "\n".join(lines).rstrip() + "\n"


def without_versions(text):
    """The document with every table row's third cell (the version) blanked."""
    def row(line):
        cells = line.split(" | ")
        return " | ".join(cells[:2] + ["-"] + cells[3:]) if line.startswith("| ") and len(cells) > 3 else line
    return [row(line) for line in text.splitlines()]


def main():
    text = generate()
    if "--check" in sys.argv[1:]:
        current = DOC.read_text() if DOC.is_file() else ""
        diff = list(difflib.unified_diff(without_versions(current), without_versions(text),
                                         "docs/DEPENDENCIES.md", "regenerated", n=0, lineterm=""))
        if diff:
            print("docs/DEPENDENCIES.md is out of date: run scripts/dependencies.py. Differences (versions aside):",
                  *diff[2:40], sep="\n", file=sys.stderr)
    else:
        DOC.write_text(text)
        diff = []
        print(f"wrote {DOC.relative_to(ROOT)}")
    for p in problems:
        print(f"dependencies: {p}", file=sys.stderr)
    return 1 if diff or problems else 0


if __name__ == "__main__":
    sys.exit(main())
