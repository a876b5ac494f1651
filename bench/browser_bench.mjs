#!/usr/bin/env node
// The browser viewer in headless Chromium (SwiftShader's WebGL2, on the CPU)
// against surfcast-serve on loopback, beside the Vulkan client
// (surfcast-view --headless --lod 1 over the same URL, lavapipe) as the
// reference: time to the first image and to convergence from opening the
// page, frames per second of the converged view (each frame waited for), and
// the browser's picking: milliseconds from a click's coordinates to the
// surfel's attributes (the id pass on the GPU, its read-back, the node's
// block decoded again), over a 5 x 4 grid of the canvas (a miss costs the
// id pass alone).
// Per set: the default camera (the set framed), 1280x720, level of detail 1 px.
//
// Usage: node bench/browser_bench.mjs [--build build] [--points 1500000] [--set DIR]... [--rounds 2]
//   --set DIR   also measure an existing tile set (e.g. one built by build_bench.py --keep)
// Writes bench/report/browser.md and prints it. Uses the viewer's own
// puppeteer-core (web/package.json) and Debian's chromium.

import { execFileSync, spawn } from "node:child_process";
import { cpSync, existsSync, mkdirSync, mkdtempSync, rmSync, symlinkSync, writeFileSync } from "node:fs";
import { cpus, tmpdir } from "node:os";
import { basename, dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const root = resolve(dirname(fileURLToPath(import.meta.url)), "..");
const { default: puppeteer } = await import(join(root, "web/node_modules/puppeteer-core/lib/esm/puppeteer/puppeteer-core.js"));

const args = process.argv.slice(2);
const opt = (name, fallback) => {
  const i = args.indexOf(name);
  return i >= 0 ? args[i + 1] : fallback;
};
const build = resolve(opt("--build", join(root, "build")));
const points = Number(opt("--points", "1500000"));
const rounds = Number(opt("--rounds", "2"));
const extraSets = args.flatMap((a, i) => (a === "--set" ? [resolve(args[i + 1])] : []));
const width = 1280, height = 720;

const work = mkdtempSync(join(tmpdir(), "surfcast-browser-bench-"));
const sets = join(work, "sets");
mkdirSync(sets);
const names = ["scene"];
execFileSync(join(build, "bin/surfcast-build"), ["-q", "--default-scene", "--scene-points", String(points), "-o", join(sets, "scene")]);
for (const s of extraSets) {
  symlinkSync(s, join(sets, basename(s)));
  names.push(basename(s));
}
// surfcast-serve never serves symlinked sets: copy them.
for (const s of extraSets) {
  rmSync(join(sets, basename(s)));
  cpSync(s, join(sets, basename(s)), { recursive: true });
}

const serve = spawn(join(build, "bin/surfcast-serve"), [sets, "--bind", "127.0.0.1:0", "--log", "errors"]);
let log = "";
serve.stderr.on("data", (d) => (log += d));
for (let i = 0; i < 100 && !/on http:\/\/127\.0\.0\.1:\d+/.test(log); ++i) await new Promise((r) => setTimeout(r, 50));
const base = `http://127.0.0.1:${log.match(/on http:\/\/127\.0\.0\.1:(\d+)/)[1]}`;

const browser = await puppeteer.launch({ executablePath: "/usr/bin/chromium", headless: true,
  args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"], protocolTimeout: 3600000 });

async function browserRun(name) {
  const page = await browser.newPage();
  await page.setViewport({ width, height });
  const t0 = Date.now();
  await page.goto(`${base}/?set=/sets/${name}&panel=0`);  // the canvas the whole 1280x720, as surfcast-view's image
  await page.waitForFunction("window.surfcast && (window.surfcast.converged || window.surfcast.errors.length > 0)",
                             { timeout: 1800000, polling: 200 });
  const s = await page.evaluate(() => window.surfcast);
  if (s.errors.length) throw new Error(`${name}: ${s.errors.join("; ")}`);
  const frameMs = await page.evaluate(() => window.surfcastTimeFrames(2));
  const pick = await page.evaluate(async () => {
    const view = document.getElementById("view"), w = view.clientWidth, h = view.clientHeight;
    let hits = 0;
    const t0 = performance.now();
    for (let i = 0; i < 5; ++i)
      for (let j = 0; j < 4; ++j) hits += (await window.surfcastPick((i + 0.5) * w / 5, (j + 0.5) * h / 4)) ? 1 : 0;
    return { ms: (performance.now() - t0) / 20, hits };
  });
  await page.close();
  return { first: s.firstImageMs / 1000, converged: s.convergedMs / 1000, fps: 1000 / frameMs, pickMs: pick.ms, pickHits: pick.hits, splats: s.splats,
           nodes: s.nodes, mb: s.bytes / 1e6, requests: s.requests, wall: (Date.now() - t0) / 1000, camera: s.camera };
}

function vulkanRun(name, camera) {
  const lines = execFileSync(join(build, "bin/surfcast-view"), ["--headless", `${base}/sets/${name}`, "--lod", "1", "--camera",
    camera, "--size", `${width}x${height}`, "--out", join(work, "v.png")], { encoding: "utf8" }).trim().split("\n").map(JSON.parse);
  const first = lines.find((l) => l.splats > 0) ?? lines[lines.length - 1];
  const last = lines[lines.length - 1];
  const repeat = execFileSync(join(build, "bin/surfcast-view"), ["--headless", join(sets, name), "--lod", "1", "--camera", camera,
    "--size", `${width}x${height}`, "--out", join(work, "v.png"), "--repeat", "3"], { encoding: "utf8" }).trim().split("\n");
  const gpuMs = JSON.parse(repeat[repeat.length - 1]).gpu_ms;
  return { first: first.time_s, converged: last.time_s, fps: 1000 / gpuMs, splats: last.splats, nodes: last.nodes };
}

const rows = [];
for (const name of names) {
  for (let r = 0; r < rounds; ++r) {
    const b = await browserRun(name);
    const v = vulkanRun(name, b.camera);
    rows.push({ name, b, v });
    console.error(`${name} round ${r + 1}: browser ${JSON.stringify(b)}; vulkan ${JSON.stringify(v)}`);
  }
}
await browser.close();
serve.kill();

const f = (x, d = 2) => x.toFixed(d);
const model = cpus()[0]?.model ?? "?";
let md = `### Browser viewer against the Vulkan client (${new Date().toISOString().slice(0, 10)})\n\n`;
md += `${model}, ${cpus().length} cores; headless Chromium (SwiftShader WebGL2, CPU) and surfcast-view --headless (lavapipe, CPU), `;
md += `both streaming from surfcast-serve on loopback; ${width}x${height}, the set framed, level of detail 1 px. `;
md += "`node bench/browser_bench.mjs" + (points !== 1500000 ? ` --points ${points}` : "") +
      extraSets.map((s) => ` --set ${basename(s)}`).join("") + "`.\n\n";
md += "| set | client | first image s | converged s | frames/s (converged view) | pick ms (hits of 20) | nodes | splats |\n";
md += "|---|---|---:|---:|---:|---:|---:|---:|\n";
for (const { name, b, v } of rows) {
  md += `| ${name} | browser (SwiftShader) | ${f(b.first)} | ${f(b.converged)} | ${f(b.fps, 3)} | ${f(b.pickMs, 0)} (${b.pickHits}) | ${b.nodes} | ${b.splats} |\n`;
  md += `| ${name} | surfcast-view (lavapipe) | ${f(v.first)} | ${f(v.converged)} | ${f(v.fps, 2)} | | ${v.nodes} | ${v.splats} |\n`;
}
mkdirSync(join(root, "bench/report"), { recursive: true });
writeFileSync(join(root, "bench/report/browser.md"), md);
console.log(md);
rmSync(work, { recursive: true, force: true });
