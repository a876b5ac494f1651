// The npm package "surfcast" (build.mjs writes it into the build folder's
// web-package/) as an app gets it: `npm pack`, then a fresh app in a temporary
// folder that installs the tarball with npm, imports "surfcast" and
// "surfcast/three", type-checks against the shipped declarations, bundles
// with esbuild, and streams a set from surfcast-serve in headless Chromium to
// the image surfcast-view draws. Nothing is downloaded (npm runs --offline).
// Needs SURFCAST_BUILD (the CMake build folder: bin/ and web-package/); CTest
// sets it. Without Chromium the browser case fails under CI and is skipped elsewhere.

import { after, before, describe, test } from "node:test";
import assert from "node:assert/strict";
import { execFileSync, spawn } from "node:child_process";
import { copyFileSync, existsSync, mkdirSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { build as esbuild } from "esbuild";
import { PNG } from "pngjs";
import puppeteer from "puppeteer-core";
import { web } from "./load_module.mjs";
import { compare, kFarLimit, kMeanLimit, viewReference, waitFor, watchProblems } from "./view_reference.mjs";

const buildDir = process.env.SURFCAST_BUILD ?? join(web, "..", "build");
const bin = (name) => join(buildDir, "bin", name);
const packageDir = join(buildDir, "web-package");
const npm = process.env.NPM ?? "npm";
const chromium = ["/usr/bin/chromium", "/usr/bin/chromium-browser"].find(existsSync);
if (!chromium && process.env.CI) throw new Error("Chromium is missing (scripts/setup.sh installs it); CI is set, so this fails");
const skip = chromium ? false : "Chromium is missing: run scripts/setup.sh";
const size = { width: 640, height: 480 };
const camera = "4,-7,3.5,0,0,0.5,0,0,1,45";
// What the package's peer dependency is tested with: the versions web/ pins.
const pins = JSON.parse(readFileSync(join(web, "package.json"), "utf8")).dependencies;

let work, app, manifest, packed, serve, browser;

// npm in `cwd`, never asking the registry (--offline fails on what the
// cache lacks rather than fetching it).
function runNpm(args, cwd) {
  return execFileSync(npm, [...args, "--offline", "--no-audit", "--no-fund", "--loglevel=error"], {
    cwd, encoding: "utf8", env: { ...process.env, npm_config_update_notifier: "false" } });
}

// The app's lockfile: three and @types/three with what they depend on,
// entries copied from web/package-lock.json. npm then takes each tarball by
// its integrity from the npm cache that `npm ci` in web/ filled (the build's
// npm step), offline, as an app installs from its lockfile. (Linking
// web/node_modules instead would let npm install the linked packages'
// dependencies into web/node_modules.)
function appLockfile(dependencies) {
  const locked = JSON.parse(readFileSync(join(web, "package-lock.json"), "utf8")).packages;
  const packages = { "": { name: "surfcast-app", dependencies } };
  // Node's resolution over the lockfile's paths: the nearest node_modules/NAME up from `from`.
  const resolve = (from, name) => {
    for (let dir = from; ; dir = dir.slice(0, Math.max(0, dir.lastIndexOf("/node_modules/")))) {
      const path = dir ? `${dir}/node_modules/${name}` : `node_modules/${name}`;
      if (locked[path]) return path;
      if (!dir) throw new Error(`web/package-lock.json has no ${name} for ${from || "the root"}`);
    }
  };
  const add = (path) => {
    if (packages[path]) return;
    const { dev, devOptional, ...entry } = locked[path];  // the app's own dependencies, not dev ones
    packages[path] = entry;
    for (const name of Object.keys(entry.dependencies ?? {})) add(resolve(path, name));
  };
  for (const name of ["three", "@types/three"]) add(resolve("", name));
  return { name: "surfcast-app", lockfileVersion: 3, requires: true, packages };
}

// The app: a page, and a module that opens the set its URL names, as
// examples/embed.html does.
const kIndexHtml = `<!doctype html>
<html lang="en">
<head><meta charset="utf-8"><title>An app with Surfcast</title><link rel="icon" href="data:,">
<style>html, body { margin: 0; height: 100%; overflow: hidden; } canvas { display: block; width: 100%; height: 100%; }</style>
</head>
<body><canvas id="view"></canvas><script type="module" src="main.js"></script></body>
</html>
`;
const kMainJs = `import { parseCamera, SurfcastViewer } from "surfcast";

const params = new URLSearchParams(location.search);
const camera = params.get("camera");
const viewer = await SurfcastViewer.open(document.getElementById("view"), new URL(params.get("set"), location.href).href,
                                         { camera: camera ? parseCamera(camera) : undefined, colorBy: "elevation" });
window.app = { viewer };
`;
// Both entry points in TypeScript: one SurfcastViewer type for both, and
// real types (an invalid mode is an error, not an any).
const kCheckTs = `import { parseCamera, SurfcastViewer, type ViewerOptions, type ViewerState } from "surfcast";
import { type LayerOptions, SurfcastLayer } from "surfcast/three";
import * as THREE from "three";

const options: ViewerOptions = { camera: parseCamera("${camera}"), colorBy: "elevation", splatBudget: 1e6 };
export async function open(canvas: HTMLCanvasElement): Promise<ViewerState> {
  const viewer = await SurfcastViewer.open(canvas, "/sets/scene", options);
  viewer.setColorBy("rgb");
  return viewer.state;
}
export async function layer(renderer: THREE.WebGLRenderer, scene: THREE.Scene, camera: THREE.PerspectiveCamera): Promise<SurfcastViewer> {
  const layerOptions: LayerOptions = { origin: [0, 0, 0], detail: 2 };
  const layer = await SurfcastLayer.open(renderer, "/sets/scene", layerOptions);
  layer.render(scene, camera);
  return layer.viewer;
}
// @ts-expect-error: no such mode
export const wrong: ViewerOptions = { mode: "voxels" };
`;
// Three with the layer, bundled: three's own copy alone.
const kThreeJs = `import * as THREE from "three";
import { SurfcastLayer } from "surfcast/three";
import { SurfcastViewer } from "surfcast";
window.app = { THREE, SurfcastLayer, SurfcastViewer };
`;

describe("the npm package", () => {
  before(async () => {
    assert.ok(existsSync(join(packageDir, "package.json")), `${packageDir} is missing: build the target web`);
    work = mkdtempSync(join(tmpdir(), "surfcast-package-"));
    manifest = JSON.parse(readFileSync(join(packageDir, "package.json"), "utf8"));
    [packed] = JSON.parse(runNpm(["pack", "--json", "--pack-destination", work], packageDir));
    // A fresh app beside the tarball, installing it as a file dependency.
    app = join(work, "app");
    mkdirSync(app);
    const dependencies = { surfcast: `file:../${packed.filename}`, three: pins.three, "@types/three": pins["@types/three"] };
    writeFileSync(join(app, "package.json"), JSON.stringify({ name: "surfcast-app", private: true, type: "module", dependencies }, null, 2));
    writeFileSync(join(app, "package-lock.json"), JSON.stringify(appLockfile(dependencies), null, 2));
    for (const [name, text] of [["index.html", kIndexHtml], ["main.js", kMainJs], ["check.ts", kCheckTs], ["three.js", kThreeJs]])
      writeFileSync(join(app, name), text);
    try {
      runNpm(["install"], app);
    } catch (e) {
      throw new Error(`npm install --offline in the app failed (the npm cache lacks a tarball web/package-lock.json pins? ` +
                      `npm ci in web/ fills it): ${e.stderr}`);
    }
  });

  after(async () => {
    await browser?.close();
    serve?.kill();
    if (work) rmSync(work, { recursive: true, force: true });
  });

  test("the tarball: exactly the files the manifest lists, two entry points, three a peer", () => {
    assert.equal(manifest.name, "surfcast");
    assert.equal(manifest.private, undefined);
    assert.equal(manifest.license, "Apache-2.0");
    assert.deepEqual(packed.files.map((f) => f.path).sort(), [...manifest.files, "LICENSE", "README.md", "package.json"].sort());
    for (const entry of [".", "./three"]) {
      const e = manifest.exports[entry];
      assert.ok(manifest.files.includes(e.default.slice(2)) && manifest.files.includes(e.types.slice(2)), entry);
    }
    assert.equal(manifest.dependencies, undefined, "nothing installed with it");
    assert.ok(manifest.peerDependencies.three && manifest.peerDependenciesMeta.three.optional);
    // Installed as npm unpacked it.
    const installed = join(app, "node_modules", "surfcast");
    assert.deepEqual(JSON.parse(readFileSync(join(installed, "package.json"), "utf8")).files, manifest.files);
    assert.match(readFileSync(join(installed, "dist", "surfcast-three.js"), "utf8"), /^import \* as THREE from "three";$/m);
  });

  test("its declarations type-check an app's TypeScript (bundler and Node16 resolution)", () => {
    // Every declaration file checked once (skipLibCheck off: else an import
    // in one that does not resolve goes unseen; 10-15 s, three's types are
    // large); the exports' resolution under Node16 too.
    for (const [name, module, resolution, skipLibCheck] of [["tsconfig.json", "ESNext", "Bundler", false],
                                                            ["tsconfig.node16.json", "Node16", "Node16", true]]) {
      writeFileSync(join(app, name), JSON.stringify({ compilerOptions: { target: "ES2022", module, moduleResolution: resolution,
        lib: ["ES2022", "DOM"], strict: true, noEmit: true, skipLibCheck, types: [] }, files: ["check.ts"] }));
      try {
        execFileSync(process.execPath, [join(web, "node_modules", "typescript", "bin", "tsc"), "-p", join(app, name)], { encoding: "utf8" });
      } catch (e) {
        assert.fail(`tsc -p ${name}: ${e.stdout}${e.stderr}`);
      }
    }
  });

  test("bundled with three: one copy of three, one of the component", async () => {
    const { outputFiles, metafile } = await esbuild({ entryPoints: [join(app, "three.js")], absWorkingDir: app, bundle: true,
      format: "esm", write: false, metafile: true, outfile: join(app, "three-bundle.js"), logLevel: "warning" });
    const bundle = outputFiles[0].text;
    assert.equal(bundle.match(/\bREVISION\d* = "\d+"/g)?.length, 1, "three once");
    const inputs = Object.keys(metafile.inputs).filter((p) => p.includes("node_modules/surfcast/"));
    assert.equal(inputs.filter((p) => /\/dist\/chunk-[^/]+\.js$/.test(p)).length, 1, `${inputs}`);
  });

  test("an app bundled with esbuild streams a set from surfcast-serve to surfcast-view's image", { skip }, async (t) => {
    // The app's build: its module bundled, the page, and the decoder's files
    // copied beside the bundle (esbuild does not follow new URL(..., import.meta.url)).
    const dist = join(app, "dist");
    const { metafile } = await esbuild({ entryPoints: [join(app, "main.js")], absWorkingDir: app, bundle: true, format: "esm",
      outdir: dist, metafile: true, logLevel: "warning" });
    assert.ok(!Object.keys(metafile.inputs).some((p) => p.includes("node_modules/three/")), "the component alone needs no three");
    copyFileSync(join(app, "index.html"), join(dist, "index.html"));
    for (const f of ["decode_worker.js", "draco_decoder.js", "draco_decoder.wasm"])
      copyFileSync(join(app, "node_modules", "surfcast", "dist", f), join(dist, f));
    const sets = join(work, "sets");
    // Small nodes, so that the view streams several levels.
    execFileSync(bin("surfcast-build"), ["-q", "--default-scene", "--scene-points", "20000", "--capacity", "2000", "-o",
                                        join(sets, "scene")]);
    serve = spawn(bin("surfcast-serve"), [sets, "--web", dist, "--bind", "127.0.0.1:0", "--log", "errors"], { stdio: ["ignore", "pipe", "pipe"] });
    let log = "";
    serve.stdout.on("data", (d) => (log += d));
    serve.stderr.on("data", (d) => (log += d));
    const url = `http://127.0.0.1:${await waitFor(() => log.match(/on http:\/\/127\.0\.0\.1:(\d+)/)?.[1], `surfcast-serve: ${log}`)}`;

    browser = await puppeteer.launch({ executablePath: chromium, headless: true,
      args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", `--window-size=${size.width},${size.height}`] });
    const page = await browser.newPage();
    await page.setViewport(size);
    const problems = watchProblems(page);
    await page.goto(`${url}/?set=/sets/scene&camera=${camera}`);
    await page.waitForFunction("window.app && (window.app.viewer.state.converged || window.app.viewer.state.errors.length > 0)",
                               { timeout: 60000 });
    const state = await page.evaluate(() => ({ ...window.app.viewer.state }));
    const png = PNG.sync.read(await page.screenshot({ type: "png" }));
    await page.close();
    assert.deepEqual(problems, []);
    assert.deepEqual(state.errors, []);
    assert.equal(state.converged, true);
    assert.ok(state.nodes > 1 && state.splats > 0, `${state.nodes} nodes, ${state.splats} splats`);
    const ref = viewReference(bin("surfcast-view"), `${url}/sets/scene`,
                              { camera, size, out: join(work, "ref.png"), extra: ["--color-by", "elevation"] });
    assert.equal(ref.json.converged, true);
    assert.equal(state.splats, ref.json.splats, "the same splats at convergence");
    assert.equal(state.nodesCrc, ref.json.nodes_crc, "the same nodes as surfcast-view");
    const d = compare(png, ref.png);
    t.diagnostic(`the app: ${state.nodes} nodes, ${state.splats} splats, mean abs ${d.mean.toFixed(3)}, far ${d.far.toFixed(5)}`);
    assert.ok(d.mean < kMeanLimit && d.far < kFarLimit, `mean abs ${d.mean}, far ${d.far}`);
  });
});
