#!/usr/bin/env node
// Explicit against implicit tiling of a 3D Tiles export (docs/EXPORT.md,
// "Tiling"): for each, the export's time and its tree's bytes (tileset.json
// and subtree files, raw and gzipped as a server would send them), then
// CesiumJS in headless Chromium (SwiftShader) opening it from nginx on
// loopback, from one camera over the set (south of it, looking at its
// centre from above): milliseconds from the page's start to the
// tileset ready (tileset.json read), to the first tile's content, and to
// every tile of the view; and the tree's bytes and requests it fetched.
// Rounds alternate the two.
//
// Usage: node bench/tiles3d_bench.mjs SET [--build build] [--rounds 2] [--sse 16]
// Prints Markdown.

import { execFileSync } from "node:child_process";
import { mkdirSync, mkdtempSync, readdirSync, readFileSync, rmSync } from "node:fs";
import { gzipSync } from "node:zlib";
import { tmpdir } from "node:os";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const root = resolve(dirname(fileURLToPath(import.meta.url)), "..");
const { launch, startPages } = await import(join(root, "web", "test", "consumers.mjs"));

const args = process.argv.slice(2);
const opt = (name, fallback) => (args.includes(name) ? args[args.indexOf(name) + 1] : fallback);
const set = args[0];
if (!set || set.startsWith("--")) {
  console.error("usage: node bench/tiles3d_bench.mjs SET [--build build] [--rounds 2] [--sse 16]");
  process.exit(2);
}
const build = resolve(opt("--build", join(root, "build")));
const rounds = Number(opt("--rounds", "2"));
const sse = Number(opt("--sse", "16"));
const chromium = "/usr/bin/chromium";

const work = mkdtempSync(join(tmpdir(), "surfcast-tiles3d-bench-"));
const children = [];
const pagesRoot = join(work, "www");
const url = await startPages(work, pagesRoot, children);
mkdirSync(join(pagesRoot, "sets"));
const browser = await launch(chromium);

// The tree's files: tileset.json and subtrees/*, with raw and gzipped bytes.
function treeBytes(dir) {
  const files = [join(dir, "tileset.json")];
  try {
    for (const f of readdirSync(join(dir, "subtrees"))) files.push(join(dir, "subtrees", f));
  } catch {}
  let raw = 0, gz = 0;
  for (const f of files) {
    const b = readFileSync(f);
    raw += b.length;
    gz += gzipSync(b).length;
  }
  return { files: files.length, raw, gz };
}

// South of the set's bounds and above them, looking at their centre.
const info = JSON.parse(readFileSync(join(set, "tileset.json"), "utf8"));
const [lo, hi] = [info.bounds.min, info.bounds.max];
const c = lo.map((v, a) => (v + hi[a]) / 2), size = Math.max(hi[0] - lo[0], hi[1] - lo[1]);
const camera = [c[0], lo[1] - 0.6 * size, hi[2] + 0.6 * size, ...c, 0, 0, 1, 45].join(",");

const rows = [];
try {
  const exported = {};
  for (const tiling of ["explicit", "implicit"]) {
    const out = join(pagesRoot, "sets", tiling);
    const t0 = process.hrtime.bigint();
    execFileSync(join(build, "bin", "surfcast-export"), [set, "--format", "3dtiles", "--as", "points", "--tiling", tiling, "-q", "-o", out]);
    exported[tiling] = { seconds: Number(process.hrtime.bigint() - t0) / 1e9, ...treeBytes(out) };
  }
  for (let round = 0; round < rounds; ++round)
    for (const tiling of ["explicit", "implicit"]) {
      const page = await browser.newPage();
      await page.setViewport({ width: 640, height: 480 });
      let treeFetched = 0, treeRequests = 0;
      page.on("response", async (r) => {
        if (!/tileset\.json$|\.subtree$/.test(r.url())) return;
        ++treeRequests;
        treeFetched += (await r.buffer().catch(() => Buffer.alloc(0))).length;
      });
      await page.goto(`${url}/cesium.html?tileset=sets/${tiling}/tileset.json&sse=${sse}&camera=${camera}`);
      await page.waitForFunction("window.cesiumState.loadedMs !== null || window.cesiumState.errors.length > 0", { timeout: 600000 });
      const s = await page.evaluate("window.cesiumState");
      if (s.errors.length) throw new Error(`${tiling}: ${s.errors.join("; ")}`);
      rows.push({ tiling, round, ...s, treeFetched, treeRequests });
      await page.close();
    }
  console.log(`Set: ${set} (${info.surfels} surfels, ${info.nodes} nodes, ${info.levels} levels); CesiumJS maximumScreenSpaceError ${sse}, ` +
              `640x480, camera ${camera}\n`);
  console.log("| tiling | export s | tree files | tree bytes | gzipped | round | ready ms | first tile ms | view loaded ms | tiles | tree bytes fetched (requests) |");
  console.log("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
  for (const r of rows) {
    const e = exported[r.tiling];
    console.log(`| ${r.tiling} | ${e.seconds.toFixed(1)} | ${e.files} | ${e.raw} | ${e.gz} | ${r.round + 1} | ${r.readyMs.toFixed(0)} | ` +
                `${r.firstTileMs.toFixed(0)} | ${r.loadedMs.toFixed(0)} | ${r.tiles} | ${r.treeFetched} (${r.treeRequests}) |`);
  }
} finally {
  await browser.close();
  for (const c of children) c.kill();
  rmSync(work, { recursive: true, force: true });
}
