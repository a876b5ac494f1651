// The splat and 3D Tiles consumers' pages (examples/cesium.html and
// spark.html) in headless Chromium, from nginx on loopback: shared by
// test/exports.test.mjs and bench/splat_bench.mjs.

import { spawn } from "node:child_process";
import { copyFileSync, mkdirSync, mkdtempSync, symlinkSync, writeFileSync } from "node:fs";
import { createServer } from "node:net";
import { join } from "node:path";
import { PNG } from "pngjs";
import puppeteer from "puppeteer-core";
import { web } from "./load_module.mjs";
import { watchProblems } from "./view_reference.mjs";

export const width = 640, height = 480;
export const chromiumArgs = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", `--window-size=${width},${height}`];

// The set's (z-up) axes as a splat file's, and back: glTF's and SPZ's y up
// (x, z, -y), the 3D Gaussian splatting PLY's y down (x, -z, y).
export const toYUp = (v) => [v[0], v[2], -v[1]];
export const toYDown = (v) => [v[0], -v[2], v[1]];
export const fromYUp = (v) => [v[0], -v[2], v[1]];
export const fromYDown = (v) => [v[0], v[2], -v[1]];

// A surfcast-view camera (eye, target, up, fov; world) in a splat file's
// axes about `origin`.
export function cameraIn(camera, origin, axes) {
  const v = camera.split(",").map(Number);
  const rel = (p) => p.map((x, a) => x - origin[a]);
  return [...axes(rel(v.slice(0, 3))), ...axes(rel(v.slice(3, 6))), ...axes(v.slice(6, 9)), v[9]].join(",");
}

// nginx serving `root` (the pages, the consumers' own builds linked beside
// them, the exports below) from a free port; its process goes into `children`.
export async function startPages(work, root, children) {
  const modules = join(web, "node_modules");
  mkdirSync(root, { recursive: true });
  symlinkSync(join(modules, "cesium", "Build", "Cesium"), join(root, "cesium"));
  for (const f of ["three.module.js", "three.core.js"]) symlinkSync(join(modules, "three", "build", f), join(root, f));
  symlinkSync(join(modules, "three", "examples", "jsm"), join(root, "three-addons"));
  symlinkSync(join(modules, "@sparkjsdev", "spark", "dist", "spark.module.js"), join(root, "spark.module.js"));
  for (const f of ["cesium.html", "spark.html"]) copyFileSync(join(web, "examples", f), join(root, f));
  for (let attempt = 0; attempt < 5; ++attempt) {
    const port = await new Promise((resolve) => {
      const s = createServer().listen(0, "127.0.0.1", () => {
        const { port } = s.address();
        s.close(() => resolve(port));
      });
    });
    const prefix = mkdtempSync(join(work, "nginx-"));
    writeFileSync(join(prefix, "nginx.conf"), `daemon off; master_process off; worker_processes 1; pid ${prefix}/nginx.pid;
error_log stderr; events { worker_connections 64; }
http { access_log off; types { text/html html; text/javascript js; text/css css; application/wasm wasm; application/json json;
  model/gltf-binary glb; image/png png; }
  default_type application/octet-stream; client_body_temp_path ${prefix}; proxy_temp_path ${prefix}; fastcgi_temp_path ${prefix};
  uwsgi_temp_path ${prefix}; scgi_temp_path ${prefix};
  server { listen 127.0.0.1:${port}; root ${root}; } }
`);
    const child = spawn("/usr/sbin/nginx", ["-e", "stderr", "-p", prefix, "-c", join(prefix, "nginx.conf")], { stdio: "ignore" });
    children.push(child);
    for (let i = 0; i < 60; ++i) {
      if (await fetch(`http://127.0.0.1:${port}/cesium.html`).then((r) => r.ok, () => false)) return `http://127.0.0.1:${port}`;
      await new Promise((r) => setTimeout(r, 50));
    }
    child.kill();
  }
  throw new Error("nginx did not start");
}

export async function launch(chromium) {
  return puppeteer.launch({ executablePath: chromium, headless: true, args: chromiumArgs });
}

// Covered pixels of an image: brighter than the background by more than
// antialiasing's faintest edge, outside the bottom-left corner where Cesium's
// credit lay over screenshots (the canvas has none; the corner is left out of
// both images alike, so that the measures stay those of earlier runs).
export function coverage(img) {
  const m = new Uint8Array(width * height);
  for (let y = 0; y < height; ++y)
    for (let x = 0; x < width; ++x) {
      const i = y * width + x;
      m[i] = !(y >= height - 40 && x < 160) && img.data[4 * i] + img.data[4 * i + 1] + img.data[4 * i + 2] > 30 ? 1 : 0;
    }
  return m;
}

// The page's WebGL canvas as the page drew it (both pages keep the drawing
// buffer): read in the page, between two of its frames. Chromium's own
// screenshot waits for a compositor frame, which these pages' slow frames in
// SwiftShader delay by 9-15 s each (bench/RELIABILITY.md, "CI stages").
export async function canvasImage(page) {
  const url = await page.evaluate(() => document.querySelector("canvas").toDataURL("image/png"));
  const png = PNG.sync.read(Buffer.from(url.slice(url.indexOf(",") + 1), "base64"));
  if (png.width !== width || png.height !== height) throw new Error(`the canvas is ${png.width} x ${png.height}, not ${width} x ${height}`);
  return png;
}

// A page at `url` once its state object (`counter`: loaded, errors, frames)
// says loaded and the view has settled: `frames` drawn after loading, then
// two images of the canvas, two frames apart, covering the same pixels to 0.5 % of
// the view (blending order moves a few edge pixels between frames). Returns
// the state, the last image and the page's problems (console errors,
// page errors, failed requests, HTTP errors).
export async function settledView(browser, url, counter, frames) {
  const { page, problems } = await openPage(browser);
  try {
    const state = await load(page, url, counter);
    if (state.errors.length) return { state, png: null, problems };
    const loadedAt = state.frames;
    let png, last = -1, wait = frames;
    for (let i = 0; ; ++i) {
      if (i === 20) throw new Error(`${url}: the view did not settle in 20 images`);
      const now = await page.evaluate(`${counter}.frames`);
      await page.waitForFunction(`${counter}.frames >= ${Math.max(now + 2, loadedAt + wait)}`, { timeout: 180000 });
      wait = 0;
      png = await canvasImage(page);
      const covered = coverage(png).reduce((a, b) => a + b, 0);
      if (covered > 0 && Math.abs(covered - last) <= 0.005 * width * height) break;
      last = covered;
    }
    return { state: await page.evaluate(counter), png, problems };
  } finally {
    await page.close();
  }
}

// A page at `url` once its state object says loaded, its state and problems
// as settledView's, without waiting for a frame.
export async function loadedView(browser, url, counter) {
  const { page, problems } = await openPage(browser);
  try {
    return { state: await load(page, url, counter), problems };
  } finally {
    await page.close();
  }
}

// A page at the consumers' size whose problems (console errors, page errors,
// failed requests, HTTP errors) go into `problems`.
async function openPage(browser) {
  const page = await browser.newPage();
  await page.setViewport({ width, height });
  const problems = watchProblems(page);
  return { page, problems };
}

// Goes to `url` and waits until `counter` says loaded or holds errors; its state.
async function load(page, url, counter) {
  await page.goto(url);
  await page.waitForFunction(`${counter}.loaded || ${counter}.errors.length > 0`, { timeout: 180000 });
  return page.evaluate(counter);
}
