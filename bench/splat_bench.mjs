#!/usr/bin/env node
// Which Gaussians make the splat consumers' images closest to
// surfcast-view's (docs/EXPORT.md, "Gaussians"): for each standard deviation
// scale (--splat-scale) and opacity (--splat-opacity), CesiumJS drawing the
// 3D Tiles splats and Spark drawing the SPZ file, in headless Chromium
// (SwiftShader), at one camera per set, against surfcast-view --headless
// (lavapipe, unlit) at the same camera: FLIP (NVIDIA's flip-evaluator, LDR, from
// bench/.venv), IoU of the covered pixels, and the mean colour difference
// over the pixels off both silhouettes.
//
// Usage: node bench/splat_bench.mjs [--build build] [--scales 0.75,1,1.25] [--opacities 1,0.7] [--sets NAME,...]
// Sets: two shared scans (autzen_trim.las, lion_takanawa.copc.laz), the
// built-in scene, and the accuracy harness's synthetic scenes
// (accuracy_bench.py: its surfels and cameras); --sets picks some by the
// start of their names. Prints Markdown.

import { execFileSync } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const root = resolve(dirname(fileURLToPath(import.meta.url)), "..");
const { PNG } = await import(join(root, "web", "node_modules", "pngjs", "lib", "png.js"));
const { cameraIn, launch, settledView, startPages, toYUp } = await import(join(root, "web", "test", "consumers.mjs"));

const args = process.argv.slice(2);
const opt = (name, fallback) => (args.includes(name) ? args[args.indexOf(name) + 1] : fallback);
const build = resolve(opt("--build", join(root, "build")));
const scales = opt("--scales", "0.75,1,1.25").split(",").map(Number);
const opacities = opt("--opacities", "1,0.7").split(",").map(Number);
const bin = (name) => join(build, "bin", name);
const python = join(root, "bench", ".venv", "bin", "python");

const work = mkdtempSync(join(tmpdir(), "surfcast-splat-bench-"));
const children = [];
const data = join(root, "..", "shared", "data");
let sets = [
  { name: "autzen_trim.las", build: [join(data, "autzen_trim.las")], camera: "636300,848500,900,636590,849216,430,0,0,1,45" },
  { name: "lion_takanawa.copc.laz", build: [join(data, "lion_takanawa.copc.laz")], camera: "-2.89,-4,4,-2.89,3.88,-1.165,0,0,1,45" },
  { name: "built-in scene, 300,000 points", build: ["--default-scene", "--scene-points", "300000"], camera: "4,-7,3.5,0,0,0.5,0,0,1,45" },
];
// The accuracy harness's scenes: its surfels as PLY files and its cameras.
{
  const code = `
import json, os, sys, numpy as np
sys.path.insert(0, sys.argv[1])
import accuracy_bench as ab
rng = np.random.default_rng(1)
out = []
for name, (surfaces, camera) in ab.scenes().items():
    pts, nrm, col = (np.concatenate(x) for x in zip(*(s.samples(rng) for s in surfaces)))
    ply = os.path.join(sys.argv[2], name + ".ply")
    ab.write_ply(ply, pts, nrm, col)
    out.append({"name": "harness: " + name, "build": ["--weights", "analytic", ply], "camera": camera})
print(json.dumps(out))
`;
  sets.push(...JSON.parse(execFileSync(python, ["-c", code, join(root, "bench"), work]).toString()));
}
if (opt("--sets", "")) {
  const wanted = opt("--sets", "").split(",");
  sets = sets.filter((s) => wanted.some((w) => s.name.startsWith(w) || s.name.startsWith(`harness: ${w}`)));
}

// The page's settled view (test/consumers.mjs) into `out`.
async function view(browser, url, counter, frames, out) {
  const { state, png, problems } = await settledView(browser, url, counter, frames);
  if (state.errors.length || problems.length) throw new Error(`${url}: ${[...state.errors, ...problems].join("; ")}`);
  writeFileSync(out, PNG.sync.write(png));
}

// FLIP, IoU and the inner mean colour difference of `image` against `reference`
// (the bottom-left corner, where Cesium's credit lay over screenshots, masked in both).
function score(reference, image) {
  const code = `
import sys, numpy as np, flip_evaluator as flip
from PIL import Image
a = np.asarray(Image.open(sys.argv[1]).convert("RGB")).astype(np.float32) / 255
b = np.asarray(Image.open(sys.argv[2]).convert("RGB")).astype(np.float32) / 255
a[-40:, :160] = 0; b[-40:, :160] = 0
_, f, _ = flip.evaluate(a, b, "LDR")
ma, mb = a.sum(2) > 30 / 255, b.sum(2) > 30 / 255
def inner(m):
    e = m.copy(); e[1:] &= m[:-1]; e[:-1] &= m[1:]; e[:, 1:] &= m[:, :-1]; e[:, :-1] &= m[:, 1:]; return e
e = inner(ma) & inner(mb)
print(f, (ma & mb).sum() / (ma | mb).sum(), float(np.abs(255 * (b[e].mean(0) - a[e].mean(0))).max()))
`;
  const [flip, iou, colour] = execFileSync(python, ["-c", code, reference, image]).toString().trim().split(" ").map(Number);
  return { flip, iou, colour };
}

const www = join(work, "www");
const url = await startPages(work, www, children);
const browser = await launch("/usr/bin/chromium");
const rows = [];
try {
  for (const [s, set] of sets.entries()) {
    const dir = join(www, `set${s}`);
    execFileSync(bin("surfcast-build"), ["-q", ...set.build, "-o", dir]);
    const reference = join(work, `set${s}-surfcast-view.png`);
    // Unlit, as the splat renderers draw (the built-in scene is otherwise lit).
    execFileSync(bin("surfcast-view"), ["--headless", dir, "--camera", set.camera, "--size", "640x480", "--background", "0,0,0",
                                        "--shading", "unlit", "--out", reference], { stdio: "ignore" });
    const info = JSON.parse(readFileSync(join(dir, "tileset.json"), "utf8"));
    const origin = [0, 1, 2].map((a) => (info.bounds.min[a] + info.bounds.max[a]) / 2);
    const sparkCamera = cameraIn(set.camera, origin, toYUp);
    const cases = [...scales.map((scale) => [scale, 1]), ...opacities.filter((o) => o !== 1).map((o) => [1, o])];
    for (const [scale, opacity] of cases) {
      const tag = `set${s}-${scale}-${opacity}`;
      const options = ["--splat-scale", String(scale), "--splat-opacity", String(opacity), "-q"];
      execFileSync(bin("surfcast-export"), [dir, "--format", "3dtiles", ...options, "-o", join(www, tag)]);
      execFileSync(bin("surfcast-export"), [dir, "--format", "spz", ...options, "-o", join(www, `${tag}.spz`)]);
      const cesiumPng = join(work, `${tag}-cesium.png`), sparkPng = join(work, `${tag}-spark.png`);
      await view(browser, `${url}/cesium.html?tileset=${tag}/tileset.json&camera=${set.camera}`, "window.cesiumState", 30, cesiumPng);
      await view(browser, `${url}/spark.html?splats=${tag}.spz&camera=${sparkCamera}`, "window.sparkState", 3, sparkPng);
      for (const [consumer, png] of [["CesiumJS (3D Tiles)", cesiumPng], ["Spark (SPZ)", sparkPng]]) {
        const r = score(reference, png);
        rows.push(`| ${set.name} | ${consumer} | ${scale} | ${opacity} | ${r.flip.toFixed(4)} | ${r.iou.toFixed(3)} | ${r.colour.toFixed(1)} |`);
        console.error(rows.at(-1));
      }
    }
  }
} finally {
  await browser.close();
  for (const c of children) c.kill();
}
console.log(`| set | consumer | --splat-scale | --splat-opacity | FLIP | IoU | inner mean colour, largest channel difference (of 255) |
|---|---|---:|---:|---:|---:|---:|
${rows.join("\n")}`);
rmSync(work, { recursive: true, force: true });
