#!/usr/bin/env python3
"""Time to a first image: surfcast-build --preview with a following viewer,
against the build without a preview and PotreeConverter 2, side by side.

The input is build_bench.py's one big LAS: the lion tiled 6 x 5 (10.26 M
points; --tiles 18x17 gives 104.6 M). In this one process, one after the other:

  potree    PotreeConverter (--method poisson): its set exists when it ends;
  build     surfcast-build -o OUT, no preview;
  pairs     --pairs times, one after the other: surfcast-build without a
            preview, then --preview with nothing following it: the cost of
            the preview and its refinements (versions as chunks are built) to
            the build, as the median of the pairs' ratios;
  preview   surfcast-build --preview -o OUT2, and as soon as OUT2/tileset.json
            appears, a headless viewer following it (surfcast-view --lod 1
            --follow 1 --save-redraws, the set framed at 640 x 360).

For the preview run: when the preview appears, when the follower's first
image (a frame with nodes drawn) arrives and how long lavapipe took to draw
it, the versions it showed, when the build ends, when the follower shows the
built set (converged), and whether the built set is byte for byte the build's
without a preview. Every image the follower drew is compared (FLIP) with its
last, the finished set's: the quality-over-time chart,
bench/report/preview_quality_XxY.png.

Usage: bench/.venv/bin/python bench/preview_bench.py [--work DIR] [--threads N]
Prints Markdown for bench/BENCHMARKS.md ("Previews").
"""
import argparse
import filecmp
import json
import os
import platform
import queue
import shutil
import subprocess
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import build_bench  # noqa: E402  (the tiled LAS and PotreeConverter's build)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")


def same_folders(a, b):
    names = sorted(os.listdir(a))
    return names == sorted(os.listdir(b)) and all(filecmp.cmp(os.path.join(a, n), os.path.join(b, n), shallow=False) for n in names)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="/tmp/surfcast-preview-bench")
    ap.add_argument("--threads", default=str(os.cpu_count()))
    ap.add_argument("--interval", default="2", help="--preview-interval (default 2)")
    ap.add_argument("--tiles", default="6x5", help="copies of the lion, X x Y (default 6x5)")
    ap.add_argument("--pairs", type=int, default=3, help="builds without and with --preview, one after the other (default 3)")
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    tx, ty = (int(v) for v in a.tiles.split("x"))
    las = os.path.join(a.work, f"lion_tiled_{tx}x{ty}.las")
    if not os.path.exists(las):
        build_bench.tiled_las(os.path.join(build_bench.DATA, "lion_takanawa.copc.laz"), tx, ty, las)
    points = tx * ty * 341989
    build_bench.run_measured.log = os.path.join(a.work, "run.log")
    plain, previewed, alone, potree_out = (os.path.join(a.work, n) for n in ("plain", "previewed", "alone", "potree"))
    for d in (plain, previewed, alone, potree_out):
        shutil.rmtree(d, ignore_errors=True)

    potree = build_bench.potree(build_bench.potree_binary(), [las], potree_out)
    # Built at the preview run's -o (the build record keeps it), then moved aside.
    build = build_bench.surfcast([las], previewed, "2G", a.threads)
    os.rename(previewed, plain)
    common = ["--memory", "2G", "--threads", a.threads]
    previewing = ["--preview", "--preview-interval", a.interval]

    def timed(args):
        started = time.monotonic()
        r = subprocess.run([os.path.join(BIN, "surfcast-build"), *args, las, "-o", alone, *common], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True, check=True)
        shutil.rmtree(alone)
        return time.monotonic() - started, r.stderr.count("at full detail")

    pairs = []  # (without, with --preview, versions)
    for _ in range(a.pairs):
        without, _ = timed(["-q"])
        with_preview, versions = timed(previewing)
        pairs.append((without, with_preview, versions))
    frames_dir = os.path.join(a.work, "frames")
    shutil.rmtree(frames_dir, ignore_errors=True)
    os.makedirs(frames_dir)

    start = time.monotonic()
    builder = subprocess.Popen([os.path.join(BIN, "surfcast-build"), "-q", *previewing, las, "-o", previewed, *common],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    json_path = os.path.join(previewed, "tileset.json")
    while not os.path.exists(json_path):
        if builder.poll() is not None:
            sys.exit("the build ended before a preview appeared:\n" + builder.stderr.read())
        time.sleep(0.01)
    t_preview = time.monotonic() - start
    follower = subprocess.Popen([os.path.join(BIN, "surfcast-view"), "--headless", previewed, "--lod", "1", "--size", "640x360",
                                 "--follow", "1", "--max-wait", "600", "--save-redraws", "--out",
                                 os.path.join(frames_dir, "follow.png")],
                                stdout=subprocess.PIPE, text=True)
    seen = []  # (seconds since the start, line) of every frame the follower printed
    lines = queue.Queue()
    threading.Thread(target=lambda: [lines.put((time.monotonic() - start, json.loads(l))) for l in follower.stdout],
                     daemon=True).start()
    first = None
    while first is None:
        t, line = lines.get(timeout=600)
        seen.append((t, line))
        if line["nodes"] > 0:
            first = (t, line)
    builder.wait()
    t_built = time.monotonic() - start
    if builder.returncode != 0:
        sys.exit("the build with --preview failed:\n" + builder.stderr.read())
    while True:
        t, line = lines.get(timeout=600)
        seen.append((t, line))
        if line["version"] >= 1 and line["converged"] and "preview" not in line:
            shown = (t, line)
            break
    follower.terminate()
    follower.wait()

    print(f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; `{' '.join(sys.argv)}`\n")
    print(f"Input: one LAS of {os.path.getsize(las):,} bytes, {points / 1e6:.2f} M points (the lion tiled {tx} x {ty})\n")
    print("| | seconds from the build's start |\n|---|---|")
    print(f"| PotreeConverter's set (`--method poisson`) | {potree['wall']:.2f} |")
    print(f"| surfcast-build's set, without a preview | {build['wall']:.2f} |")
    print(f"| with `--preview`: the preview published | {t_preview:.2f} |")
    print(f"| its follower's first image (lavapipe drew it in {first[1]['gpu_ms'] / 1e3:.2f} s) | {first[0]:.2f} |")
    print(f"| the set built | {t_built:.2f} ({t_built / build['wall']:.3f}x the build without a preview) |")
    print(f"| the follower showing the set, converged | {shown[0]:.2f} |")
    ratios = sorted(w / o for o, w, _ in pairs)
    if pairs:
        print(f"\nWithout and with `--preview`, nothing following, {len(pairs)} pairs one after the other: " +
              "; ".join(f"{o:.2f} s and {w:.2f} s ({w / o:.3f}x, {v} versions)" for o, w, v in pairs) +
              f"; median **{ratios[len(ratios) // 2]:.3f}x**.")
    quality(seen, os.path.join(ROOT, "bench", "report", f"preview_quality_{tx}x{ty}.png"), t_preview, t_built, potree["wall"],
            f"{points / 1e6:.2f} M-point LAS")
    print(f"\nThe set built with `--preview` is the build's without, byte for byte: "
          f"{'yes' if same_folders(plain, previewed) else 'NO'}; the preview was 1 in "
          f"{first[1].get('preview', 1)} points.")


def quality(seen, chart, t_preview, t_built, t_potree, title):
    """FLIP of each image the follower drew against its last (the finished
    set's), over time; a table and the chart."""
    import flip_evaluator as flip
    import matplotlib
    import numpy as np
    from PIL import Image
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    drawn = [(t, l) for t, l in seen if "redraw" in l]
    load = lambda path: np.asarray(Image.open(path).convert("RGB")).astype(np.float32) / 255
    final = load(drawn[-1][1]["redraw"])
    points = [(t, float(flip.evaluate(final, load(l["redraw"]), "LDR")[1]), l) for t, l in drawn]
    print("\n| seconds | version | at full detail | FLIP against the finished set |\n|---:|---:|---:|---:|")
    last = None
    for t, f, l in points:
        state = (l["version"], l.get("preview_done"))
        if state != last and l["converged"]:
            done = "preview" if l.get("preview_done") == 0 else "set" if "preview" not in l else f"{100 * l['preview_done']:.0f} %"
            print(f"| {t:.2f} | {l['version']} | {done} | {f:.4f} |")
            last = state
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.step([t for t, _, _ in points], [f for _, f, _ in points], where="post", label="surfcast-view --follow")
    ax.axvline(t_preview, color="grey", linestyle=":", label="preview published")
    ax.axvline(t_built, color="black", linestyle="--", label="surfcast-build done")
    ax.axvline(t_potree, color="tab:red", linestyle="--", label="PotreeConverter done")
    ax.set_xlabel("seconds since the build started")
    ax.set_ylabel("FLIP against the finished set")
    ax.set_title(f"{title}: the image while the build runs")
    ax.legend()
    fig.tight_layout()
    fig.savefig(chart, dpi=100)


if __name__ == "__main__":
    main()
