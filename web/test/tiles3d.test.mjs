// surfcast-export --format 3dtiles checked by its consumers, not by our own
// reader: Khronos's glTF validator on every glb, glTF-Transform reading the
// glbs back against the set as the browser client decodes it (format.ts,
// block_decode.ts, draco3d), and CesiumJS loading the tileset from nginx on
// loopback in headless Chromium. The set is autzen_trim.las from the shared
// scans (colour, intensity, classification, returns).

import { after, before, describe, test } from "node:test";
import assert from "node:assert/strict";
import { execFileSync, spawn } from "node:child_process";
import { createRequire } from "node:module";
import { existsSync, mkdtempSync, readdirSync, readFileSync, rmSync, symlinkSync, copyFileSync, mkdirSync } from "node:fs";
import { createServer } from "node:net";
import { gunzipSync } from "node:zlib";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { Logger, NodeIO } from "@gltf-transform/core";
import validator from "gltf-validator";
import { PNG } from "pngjs";
import puppeteer from "puppeteer-core";
import { loadModule, web } from "./load_module.mjs";

const build = process.env.SURFCAST_BUILD ?? join(web, "..", "build");
const bin = (name) => join(build, "bin", name);
const data = process.env.SURFCAST_DATA_DIR ?? join(web, "..", "..", "shared", "data");
const scan = join(data, "autzen_trim.las");
const chromium = ["/usr/bin/chromium", "/usr/bin/chromium-browser"].find(existsSync);
// Without the shared scans the test cannot run; under CI that is a failure, not a skip.
const skip = existsSync(scan) || process.env.CI ? false : `${scan} is missing`;

const format = await loadModule("src/format.ts");
const blocks = await loadModule("src/block_decode.ts");

let work, set, out, splats;
let cesiumUrl, cesiumBrowser;
// Over the Autzen scan from its south-west, as surfcast-view takes a camera.
const camera = "636300,848500,900,636590,849216,430,0,0,1,45";
const children = [];

function srgbFromLinear(c) {
  return c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055;
}

// The set as the browser client reads it: tileset.json, every hierarchy
// record (following pages as the streaming client does), and a decoder for
// one surfel of a node's block.
function readSet(dir) {
  const info = format.parseTileset(readFileSync(join(dir, "tileset.json"), "utf8"), "tileset.json");
  const bytes = new Uint8Array(readFileSync(join(dir, "hierarchy.bin")));
  const index = format.readHierarchyIndex(bytes, bytes.length, "hierarchy.bin");
  const nodes = new Map();
  const due = [[0, "0-0-0-0"]];
  for (let i = 0; i < due.length; ++i) {
    const [page, root] = due[i];
    const e = index.pages[page];
    for (const r of format.readHierarchyPage(index, page, bytes.subarray(e.offset, e.offset + e.records * format.kRecordBytes), root,
                                             info.blocksBytes, "hierarchy.bin")) {
      nodes.set(r.key, r);
      if (r.flags & format.kFlagChildrenInPage) due.push([r.childPage, r.key]);
    }
  }
  return { info, nodes };
}

async function startNginx(root) {
  for (let attempt = 0; attempt < 5; ++attempt) {
    const port = await new Promise((resolve) => {
      const s = createServer().listen(0, "127.0.0.1", () => {
        const { port } = s.address();
        s.close(() => resolve(port));
      });
    });
    const prefix = mkdtempSync(join(work, "nginx-"));
    const conf = join(prefix, "nginx.conf");
    execFileSync("sh", ["-c", `cat > ${conf}`], { input: `daemon off; master_process off; worker_processes 1; pid ${prefix}/nginx.pid;
error_log stderr; events { worker_connections 64; }
http { access_log off; types { text/html html; text/javascript js; text/css css; application/wasm wasm; application/json json;
  model/gltf-binary glb; image/png png; }
  default_type application/octet-stream; client_body_temp_path ${prefix}; proxy_temp_path ${prefix}; fastcgi_temp_path ${prefix};
  uwsgi_temp_path ${prefix}; scgi_temp_path ${prefix};
  server { listen 127.0.0.1:${port}; root ${root}; } }
` });
    const child = spawn("/usr/sbin/nginx", ["-e", "stderr", "-p", prefix, "-c", conf], { stdio: "ignore" });
    children.push(child);
    for (let i = 0; i < 60; ++i) {
      if (await fetch(`http://127.0.0.1:${port}/cesium.html`).then((r) => r.ok, () => false)) return `http://127.0.0.1:${port}`;
      await new Promise((r) => setTimeout(r, 50));
    }
    child.kill();
  }
  throw new Error("nginx did not start");
}

describe("3D Tiles export", { skip }, () => {
  before(() => {
    assert.ok(existsSync(scan), `${scan}: the shared scans are needed (SURFCAST_DATA_DIR)`);
    work = mkdtempSync(join(tmpdir(), "surfcast-tiles3d-"));
    set = join(work, "autzen");
    out = join(work, "autzen3d");
    execFileSync(bin("surfcast-build"), ["-q", scan, "--attributes", "all", "-o", set]);
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "--as", "points", "-q", "-o", out]);
    splats = join(work, "autzen-splats");
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "-q", "-o", splats]);  // splats: the default
  });
  after(async () => {
    await cesiumBrowser?.close();
    for (const c of children) c.kill();
    if (work) rmSync(work, { recursive: true, force: true });
  });

  test("Khronos's glTF validator: no errors or warnings in any glb", async (t) => {
    const infos = new Set();
    for (const dir of [out, splats]) {
      const files = readdirSync(join(dir, "tiles"));
      assert.ok(files.length > 1);
      for (const f of files) {
        const report = await validator.validateBytes(new Uint8Array(readFileSync(join(dir, "tiles", f))), { maxIssues: 20 });
        // The validator (2.0.0-dev.3.10, npm's newest) predates
        // KHR_gaussian_splatting: it takes the extension's attribute names
        // for application-specific ones, which must begin with "_". Those
        // two, on the splat tiles, are the only errors it may report.
        const known = (m) => m.code === "MESH_PRIMITIVE_INVALID_ATTRIBUTE" && dir === splats &&
                             /attributes\/KHR_gaussian_splatting:(SCALE|ROTATION)$/.test(m.pointer);
        const problems = report.issues.messages.filter((m) => m.severity <= 1 && !known(m));
        assert.deepEqual(problems, [], `${f}`);
        assert.equal(report.issues.numErrors, dir === splats ? 2 : 0, `${f}: ${JSON.stringify(report.issues.messages)}`);
        for (const m of report.issues.messages) if (m.severity > 1) infos.add(m.message);
      }
    }
    t.diagnostic(`infos: ${[...infos].join(" | ")}`);
  });

  test("tileset.json: one tile per node, REPLACE, errors from h, boxes nested", () => {
    const { info, nodes } = readSet(set);
    const tileset = JSON.parse(readFileSync(join(out, "tileset.json"), "utf8"));
    assert.equal(tileset.asset.version, "1.1");
    assert.equal(tileset.root.refine, "REPLACE");
    const centre = info.boundsMin.map((m, a) => (m + info.boundsMax[a]) / 2);
    assert.deepEqual(tileset.root.transform.slice(12, 15), centre, "the root carries the set's centre");
    let tiles = 0;
    const inside = (c, p) => [0, 1, 2].every((a) => c.box[a] - c.box[3 + 4 * a] >= p.box[a] - p.box[3 + 4 * a] - 1e-9 &&
                                                      c.box[a] + c.box[3 + 4 * a] <= p.box[a] + p.box[3 + 4 * a] + 1e-9);
    const walk = (tile, key, parent) => {
      ++tiles;
      const n = nodes.get(key);
      assert.ok(n, `tile ${key} has a node`);
      assert.equal(tile.content?.uri, `tiles/${key}.glb`);
      assert.ok(existsSync(join(out, tile.content.uri)));
      // A node's error is its spacing h, the distance its samples lie apart (leaves too).
      assert.ok(Math.abs(tile.geometricError - n.spacing) <= 1e-6 * n.spacing, `tile ${key}'s error`);
      if (parent) assert.ok(inside(tile.boundingVolume, parent.boundingVolume), `tile ${key} lies inside its parent`);
      const kids = tile.children ?? [];
      assert.equal(kids.length, [...Array(8).keys()].filter((c) => n.childMask & (1 << c)).length);
      let c = 0;
      for (let i = 0; i < 8; ++i) if (n.childMask & (1 << i)) walk(kids[c++], format.childKey(n, i), tile);
    };
    walk(tileset.root, "0-0-0-0", null);
    assert.equal(tiles, nodes.size);
  });

  test("round trip: glTF-Transform reads back the set's surfels", async (t) => {
    const { info, nodes } = readSet(set);
    const draco = await createRequire(import.meta.url)("draco3d").createDecoderModule({});
    const tileset = JSON.parse(readFileSync(join(out, "tileset.json"), "utf8"));
    const origin = tileset.root.transform.slice(12, 15);
    // It reads the glbs without the extensions' definitions (unlit, metadata): the attributes are the core's.
    const io = new NodeIO().setLogger(new Logger(Logger.Verbosity.ERROR));
    const blob = readFileSync(join(set, "blocks.bin"));
    const extra = info.attributes.map((a) => a.name).filter((n) => !format.kFixedAttributes.includes(n));
    const coloring = { by: "rgb", originZ: 0, elevationMin: 0, elevationMax: 1, intensityScale: 1, intensityOffset: 0,
                       intensityP2: 0, intensityP98: 1, hiddenClasses: [] };
    let compared = 0, worst = 0;
    for (const n of nodes.values()) {
      const doc = await io.readBinary(new Uint8Array(readFileSync(join(out, "tiles", `${n.key}.glb`))));
      const node = doc.getRoot().listNodes()[0];
      const prim = doc.getRoot().listMeshes()[0].listPrimitives()[0];
      const position = prim.getAttribute("POSITION"), normal = prim.getAttribute("NORMAL"), color = prim.getAttribute("COLOR_0");
      assert.equal(position.getCount(), n.surfelCount, `node ${n.key}'s point count`);
      const [tx, ty, tz] = node.getTranslation();
      const edge = format.nodeEdge(info, n.level);
      // Float offsets from the tile's centre: a few ulps of the node's size.
      const tolerance = 1e-6 * edge;
      const job = { id: 1, key: n.key, blob: blob.buffer.slice(blob.byteOffset + n.blockOffset, blob.byteOffset + n.blockOffset + n.blockSize),
                    crc: n.blockCrc, points: n.surfelCount, positionBits: n.positionBits, min: format.nodeMin(info, n), edge,
                    spacing: n.spacing, hasRadius: !!(n.flags & format.kFlagHasRadius),
                    hasEdgeWeights: !!(n.flags & format.kFlagEdgeWeights), colorBits: info.colorBits, weights: info.weights !== "none",
                    extra, coloring };
      const step = Math.max(1, Math.floor(n.surfelCount / 40));
      for (let i = 0; i < n.surfelCount; i += step) {
        const s = blocks.decodeBlock(draco, { ...job, pick: i }).picked;
        // glTF is y-up: (x, y, z) of the set is (x, z, -y) in the glb.
        const p = position.getElement(i, []), q = [p[0] + tx, p[1] + ty, p[2] + tz];
        const world = [origin[0] + q[0], origin[1] - q[2], origin[2] + q[1]];
        for (let a = 0; a < 3; ++a) {
          worst = Math.max(worst, Math.abs(world[a] - s.position[a]) / edge);
          assert.ok(Math.abs(world[a] - s.position[a]) <= tolerance, `node ${n.key} surfel ${i} axis ${a}: ${world[a]} vs ${s.position[a]}`);
        }
        // The block's normal (quantized, near unit length) made unit, as glTF asks.
        const m = normal.getElement(i, []), len = Math.hypot(...s.normal);
        assert.ok(Math.hypot(m[0] - s.normal[0] / len, -m[2] - s.normal[1] / len, m[1] - s.normal[2] / len) < 1e-6,
                  `node ${n.key} surfel ${i}'s normal`);
        // COLOR_0 is linear (glTF's definition) at 16 bits: back to the set's 8-bit sRGB exactly.
        const c = color.getElement(i, []);
        for (let k = 0; k < 3; ++k) assert.equal(Math.round(srgbFromLinear(c[k]) * 255), Math.round(s.color[k] * 255));
        assert.equal(c[3], 1);
        for (const [name, semantic] of [["classification", "_CLASSIFICATION"], ["intensity", "_INTENSITY"],
                                        ["return_number", "_RETURN_NUMBER"], ["number_of_returns", "_NUMBER_OF_RETURNS"]])
          assert.equal(prim.getAttribute(semantic).getScalar(i), s.raw[name], `node ${n.key} surfel ${i}'s ${name}`);
        ++compared;
      }
    }
    t.diagnostic(`${compared} surfels compared; largest position error ${(worst * 1e6).toFixed(3)} millionths of a node's edge`);
  });

  test("round trip: the splats' SPZ holds the set's surfels as Gaussians", async (t) => {
    const { info, nodes } = readSet(set);
    const draco = await createRequire(import.meta.url)("draco3d").createDecoderModule({});
    const tileset = JSON.parse(readFileSync(join(splats, "tileset.json"), "utf8"));
    assert.deepEqual(tileset.extensionsRequired, ["3DTILES_content_gltf"]);
    assert.deepEqual(tileset.extensions["3DTILES_content_gltf"].extensionsRequired,
                     ["KHR_gaussian_splatting", "KHR_gaussian_splatting_compression_spz_2"]);
    const origin = tileset.root.transform.slice(12, 15);
    const blob = readFileSync(join(set, "blocks.bin"));
    const extra = info.attributes.map((a) => a.name).filter((n) => !format.kFixedAttributes.includes(n));
    const coloring = { by: "rgb", originZ: 0, elevationMin: 0, elevationMax: 1, intensityScale: 1, intensityOffset: 0,
                       intensityP2: 0, intensityP98: 1, hiddenClasses: [] };
    let compared = 0;
    for (const n of nodes.values()) {
      // The glb read by hand: its JSON chunk, and the SPZ its extension points at.
      const glb = readFileSync(join(splats, "tiles", `${n.key}.glb`));
      const jsonLength = glb.readUInt32LE(12);
      const gltf = JSON.parse(glb.subarray(20, 20 + jsonLength).toString());
      const bin = glb.subarray(28 + jsonLength);
      const prim = gltf.meshes[0].primitives[0];
      const ext = prim.extensions.KHR_gaussian_splatting;
      assert.equal(ext.kernel, "ellipse");
      const view = gltf.bufferViews[ext.extensions.KHR_gaussian_splatting_compression_spz_2.bufferView];
      const spz = gunzipSync(bin.subarray(view.byteOffset, view.byteOffset + view.byteLength));
      // SPZ 2 (Niantic's load-spz.cc): header, then positions, opacities, colours, scales, rotations.
      assert.equal(spz.readUInt32LE(0), 0x5053474e);
      assert.equal(spz.readUInt32LE(4), 2);
      const count = spz.readUInt32LE(8), fraction = spz[13];
      assert.equal(count, n.surfelCount);
      assert.equal(gltf.accessors[prim.attributes.POSITION].count, count);
      const at = { position: 16, opacity: 16 + 9 * count, color: 16 + 10 * count, scale: 16 + 13 * count, rotation: 16 + 16 * count };
      assert.equal(spz.length, 16 + 19 * count);
      const m = gltf.nodes[0].matrix;
      const edge = format.nodeEdge(info, n.level);
      const job = { id: 1, key: n.key, blob: blob.buffer.slice(blob.byteOffset + n.blockOffset, blob.byteOffset + n.blockOffset + n.blockSize),
                    crc: n.blockCrc, points: n.surfelCount, positionBits: n.positionBits, min: format.nodeMin(info, n), edge,
                    spacing: n.spacing, hasRadius: !!(n.flags & format.kFlagHasRadius),
                    hasEdgeWeights: !!(n.flags & format.kFlagEdgeWeights), colorBits: info.colorBits, weights: info.weights !== "none",
                    extra, coloring };
      const step = Math.max(1, Math.floor(count / 40));
      for (let i = 0; i < count; i += step) {
        const s = blocks.decodeBlock(draco, { ...job, pick: i }).picked;
        // Positions: 24-bit fixed point with `fraction` bits, y-up, about the tile's centre.
        const p = [0, 1, 2].map((a) => (spz.readIntLE(at.position + 9 * i + 3 * a, 3)) / 2 ** fraction + m[12 + a]);
        const world = [origin[0] + p[0], origin[1] - p[2], origin[2] + p[1]];
        for (let a = 0; a < 3; ++a)
          assert.ok(Math.abs(world[a] - s.position[a]) <= 2 ** -fraction / 2 + 1e-6 * edge, `node ${n.key} surfel ${i} axis ${a}`);
        assert.equal(spz[at.opacity + i], 255, "opaque");
        // Colour: the DC coefficient at 0.15 * 255 per unit about 127.5, within one byte.
        for (let c = 0; c < 3; ++c) {
          const shown = (spz[at.color + 3 * i + c] - 127.5) / (0.15 * 255) * 0.28209479177387814 + 0.5;
          assert.ok(Math.abs(shown - s.color[c]) <= 0.5 / (0.15 * 255) * 0.28209479177387814 + 1e-9, `node ${n.key} surfel ${i} colour ${c}`);
        }
        // Scale: ln s at 16 per unit, offset 10; sigma = kernel scale * radius in the plane, 1 % of it along the normal.
        const sigma = info.kernelScale * s.radius;
        const scales = [0, 1, 2].map((a) => Math.exp(spz[at.scale + 3 * i + a] / 16 - 10));
        for (const [a, want] of [[0, sigma], [1, sigma], [2, 0.01 * sigma]])
          assert.ok(Math.abs(Math.log(scales[a] / want)) <= 1 / 32 + 1e-6, `node ${n.key} surfel ${i} scale ${a}: ${scales[a]} vs ${want}`);
        // Rotation: x, y, z at 127.5 per unit about 127.5, w >= 0; it takes z to the normal (y-up).
        const [x, y, z] = [0, 1, 2].map((a) => (spz[at.rotation + 3 * i + a] - 127.5) / 127.5);
        const w = Math.sqrt(Math.max(0, 1 - x * x - y * y - z * z));
        const nz = [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)];
        const len = Math.hypot(...s.normal), want = [s.normal[0] / len, s.normal[2] / len, -s.normal[1] / len];
        const cos = nz[0] * want[0] + nz[1] * want[1] + nz[2] * want[2];
        // Each of x, y, z rounds by up to 1/255, and w = sqrt(1 - x² - y² - z²)
        // by (|x| + |y| + |z|) / (255 w) more; a quaternion off by e turns
        // a vector by at most 2e (plus the block's own normal rounding).
        const e = Math.hypot(1 / 255, 1 / 255, 1 / 255, (Math.abs(x) + Math.abs(y) + Math.abs(z)) / (255 * w));
        assert.ok(Math.acos(Math.min(1, cos)) <= 2 * e + 1e-3, `node ${n.key} surfel ${i}: the normal off by ${Math.acos(Math.min(1, cos))} rad`);
        ++compared;
      }
    }
    t.diagnostic(`${compared} splats compared`);
  });

  // Covered pixels of a 640 x 480 image: brighter than the background by
  // more than antialiasing's faintest edge; Cesium's credit (bottom left)
  // is not the set's.
  function coverage(img) {
    const m = new Uint8Array(640 * 480);
    for (let y = 0; y < 480; ++y)
      for (let x = 0; x < 640; ++x) {
        const i = y * 640 + x;
        m[i] = !(y >= 440 && x < 160) && img.data[4 * i] + img.data[4 * i + 1] + img.data[4 * i + 2] > 30 ? 1 : 0;
      }
    return m;
  }

  // CesiumJS's view of an export (a folder under work/) at the test's camera,
  // from nginx on loopback; also the problems the page reported.
  async function cesium(folder, params) {
    if (!cesiumUrl) {
      const root = join(work, "www");
      mkdirSync(root);
      symlinkSync(join(web, "node_modules", "cesium", "Build", "Cesium"), join(root, "cesium"));
      symlinkSync(work, join(root, "sets"));
      copyFileSync(join(web, "examples", "cesium.html"), join(root, "cesium.html"));
      cesiumUrl = await startNginx(root);
      cesiumBrowser = await puppeteer.launch({ executablePath: chromium, headless: true,
        args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=640,480"] });
    }
    const page = await cesiumBrowser.newPage();
    await page.setViewport({ width: 640, height: 480 });
    const problems = [];
    page.on("console", (m) => m.type() === "error" && problems.push(`console: ${m.text()}`));
    page.on("pageerror", (e) => problems.push(`page error: ${e.message}`));
    page.on("requestfailed", (r) => problems.push(`request failed: ${r.url()} ${r.failure()?.errorText}`));
    page.on("response", (r) => r.status() >= 400 && problems.push(`HTTP ${r.status()}: ${r.url()}`));
    await page.goto(`${cesiumUrl}/cesium.html?tileset=sets/${folder}/tileset.json&camera=${camera}${params}`);
    await page.waitForFunction("window.cesiumState.loaded || window.cesiumState.errors.length > 0", { timeout: 120000 });
    const state = await page.evaluate(() => window.cesiumState);
    // Tiles load before they are drawn, and splats are drawn sorted first
    // from their snapshot, then sorted again while the camera rests: 30
    // frames after the last tile loaded (about 20 s in SwiftShader) the view
    // has settled in every run seen. Then it is done when two screenshots,
    // two frames apart, cover the same pixels to 0.5 % of the view (blending
    // order moves a few edge pixels between frames).
    const loadedAt = await page.evaluate(() => window.cesiumState.frames);
    let png, last = -1, wait = 30;
    for (let i = 0; i < 20; ++i) {
      const frames = await page.evaluate(() => window.cesiumState.frames);
      await page.waitForFunction(`window.cesiumState.frames >= ${Math.max(frames + 2, loadedAt + wait)}`, { timeout: 120000 });
      wait = 0;
      png = PNG.sync.read(await page.screenshot({ type: "png" }));
      const covered = coverage(png).reduce((a, b) => a + b, 0);
      if (covered > 0 && Math.abs(covered - last) <= 0.005 * 640 * 480) break;
      last = covered;
    }
    await page.close();
    return { state, png, problems };
  }

  // surfcast-view at the same camera, on the same black.
  let reference;
  function surfcastView() {
    if (!reference) {
      const file = join(work, "surfcast-view.png");
      execFileSync(bin("surfcast-view"), ["--headless", set, "--camera", camera, "--size", "640x480", "--background", "0,0,0",
                                          "--out", file], { stdio: "ignore" });
      reference = PNG.sync.read(readFileSync(file));
    }
    return reference;
  }

  // How `png` covers the pixels surfcast-view's image does, and the mean
  // colours of both over the pixels off either's silhouette.
  function compare(png) {
    const want = surfcastView();
    // Pixels whose four neighbours are covered too: off the silhouette.
    const inner = (m) => m.map((v, i) => v && m[i - 1] && m[i + 1] && m[i - 640] && m[i + 640] ? 1 : 0);
    const a = coverage(png), b = coverage(want), ai = inner(a), bi = inner(b);
    let both = 0, either = 0, n = 0;
    const sum = [[0, 0, 0], [0, 0, 0]];
    for (let i = 0; i < a.length; ++i) {
      both += a[i] & b[i];
      either += a[i] | b[i];
      if (!(ai[i] && bi[i])) continue;
      ++n;
      for (let c = 0; c < 3; ++c) sum[0][c] += png.data[4 * i + c], sum[1][c] += want.data[4 * i + c];
    }
    const [mine, theirs] = sum.map((s) => s.map((v) => v / n));
    return { iou: both / either, n, mine, theirs, shown: `${mine.map((v) => v.toFixed(1))} against ${theirs.map((v) => v.toFixed(1))}` };
  }

  // Mean colour off the silhouettes. Each renderer shows at a pixel a convex
  // combination of nearby surfels' stored colours (EWA: their normalized
  // Gaussian average; Cesium's points: the nearest one's; its splats: a
  // front-to-back blend), so over the n pixels both estimate the surface's
  // area-weighted mean colour. They differ by rounding (the images' 8 bits:
  // 0.5 level each; SPZ's colour bytes: 1 level) and by sampling: a pixel
  // varies about the smoothed one by the scan's colour spread (about 40
  // levels), averaged over n / 4 independent points (a point covers about 4
  // pixels here), 3 sigma of which is 3 * 40 / sqrt(n / 4) = 0.7 level at
  // n = 108,000. Hence 3 (2 where no SPZ rounding).
  function expectSameColours(result, tolerance) {
    for (let c = 0; c < 3; ++c)
      assert.ok(Math.abs(result.mine[c] - result.theirs[c]) <= tolerance, `channel ${c}: ${result.shown}`);
  }

  test("CesiumJS draws the points where surfcast-view draws the set, in its colours", { skip: chromium ? false : "Chromium is missing" },
       async (t) => {
    // Points sized by their tile's error, and no multisampling: a pixel
    // shows one point's colour, not a blend with the background.
    const { state, png, problems } = await cesium("autzen3d", "&attenuation=1&msaa=1");
    assert.deepEqual(state.errors, []);
    assert.deepEqual(problems, []);
    assert.ok(state.tiles >= 1, `${state.tiles} tiles loaded`);
    const r = compare(png);
    assert.ok(r.iou >= 0.8, `Cesium's points cover the pixels surfcast-view's splats do: IoU ${r.iou}`);
    expectSameColours(r, 2);
    t.diagnostic(`CesiumJS points: ${state.tiles} tiles, IoU ${r.iou.toFixed(3)} with surfcast-view; mean colour over ${r.n} inner pixels ${r.shown}`);
  });

  test("CesiumJS draws the splats where surfcast-view draws the set, in its colours", { skip: chromium ? false : "Chromium is missing" },
       async (t) => {
    const { state, png, problems } = await cesium("autzen-splats", "");
    assert.deepEqual(state.errors, []);
    assert.deepEqual(problems, []);
    assert.ok(state.tiles >= 1, `${state.tiles} tiles loaded`);
    const r = compare(png);
    assert.ok(r.iou >= 0.8, `Cesium's splats cover the pixels surfcast-view's do: IoU ${r.iou}`);
    expectSameColours(r, 3);
    t.diagnostic(`CesiumJS splats: ${state.tiles} tiles, IoU ${r.iou.toFixed(3)} with surfcast-view; mean colour over ${r.n} inner pixels ${r.shown}`);
  });
});
