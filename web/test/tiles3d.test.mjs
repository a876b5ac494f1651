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

let work, set, out;
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
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "-q", "-o", out]);
  });
  after(() => {
    for (const c of children) c.kill();
    if (work) rmSync(work, { recursive: true, force: true });
  });

  test("Khronos's glTF validator: no errors or warnings in any glb", async (t) => {
    const files = readdirSync(join(out, "tiles"));
    assert.ok(files.length > 1);
    const infos = new Set();
    for (const f of files) {
      const report = await validator.validateBytes(new Uint8Array(readFileSync(join(out, "tiles", f))), { maxIssues: 20 });
      assert.equal(report.issues.numErrors + report.issues.numWarnings, 0, `${f}: ${JSON.stringify(report.issues.messages)}`);
      for (const m of report.issues.messages) infos.add(m.message);
    }
    // The validator does not know EXT_structural_metadata; it says so as an info.
    t.diagnostic(`${files.length} glbs; infos: ${[...infos].join(" | ")}`);
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

  test("CesiumJS loads the tileset from nginx and draws it", { skip: chromium ? false : "Chromium is missing" }, async (t) => {
    const root = join(work, "www");
    mkdirSync(root);
    symlinkSync(join(web, "node_modules", "cesium", "Build", "Cesium"), join(root, "cesium"));
    symlinkSync(out, join(root, "autzen3d"));
    copyFileSync(join(web, "examples", "cesium.html"), join(root, "cesium.html"));
    const url = await startNginx(root);
    const browser = await puppeteer.launch({ executablePath: chromium, headless: true,
      args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=640,480"] });
    try {
      const page = await browser.newPage();
      await page.setViewport({ width: 640, height: 480 });
      const problems = [];
      page.on("console", (m) => m.type() === "error" && problems.push(`console: ${m.text()}`));
      page.on("pageerror", (e) => problems.push(`page error: ${e.message}`));
      page.on("requestfailed", (r) => problems.push(`request failed: ${r.url()} ${r.failure()?.errorText}`));
      page.on("response", (r) => r.status() >= 400 && problems.push(`HTTP ${r.status()}: ${r.url()}`));
      // Points sized by their tile's error, and no multisampling: a pixel
      // shows one point's colour, not a blend with the background.
      await page.goto(`${url}/cesium.html?tileset=autzen3d/tileset.json&camera=${camera}&attenuation=1&msaa=1`);
      await page.waitForFunction("window.cesiumState.loaded || window.cesiumState.errors.length > 0", { timeout: 120000 });
      const state = await page.evaluate(() => window.cesiumState);
      const png = PNG.sync.read(await page.screenshot({ type: "png" }));
      assert.deepEqual(state.errors, []);
      assert.deepEqual(problems, []);
      assert.ok(state.tiles >= 1, `${state.tiles} tiles loaded`);
      // The same camera in surfcast-view, on the same black.
      const ref = join(work, "surfcast-view.png");
      execFileSync(bin("surfcast-view"), ["--headless", set, "--camera", camera, "--size", "640x480", "--background", "0,0,0",
                                          "--out", ref], { stdio: "ignore" });
      const want = PNG.sync.read(readFileSync(ref));
      // Covered: brighter than the background by more than antialiasing's
      // faintest edge; Cesium's credit (bottom left) is not the set's.
      const mask = (img) => {
        const m = new Uint8Array(640 * 480);
        for (let y = 0; y < 480; ++y)
          for (let x = 0; x < 640; ++x) {
            const i = y * 640 + x;
            m[i] = !(y >= 440 && x < 160) && img.data[4 * i] + img.data[4 * i + 1] + img.data[4 * i + 2] > 30 ? 1 : 0;
          }
        return m;
      };
      // Pixels whose four neighbours are covered too: off either silhouette.
      const inner = (m) => m.map((v, i) => v && m[i - 1] && m[i + 1] && m[i - 640] && m[i + 640] ? 1 : 0);
      const a = mask(png), b = mask(want), ai = inner(a), bi = inner(b);
      let both = 0, either = 0, n = 0;
      const sum = [[0, 0, 0], [0, 0, 0]];
      for (let i = 0; i < a.length; ++i) {
        both += a[i] & b[i];
        either += a[i] | b[i];
        if (!(ai[i] && bi[i])) continue;
        ++n;
        for (let c = 0; c < 3; ++c) sum[0][c] += png.data[4 * i + c], sum[1][c] += want.data[4 * i + c];
      }
      const iou = both / either;
      assert.ok(iou >= 0.8, `Cesium's points cover the pixels surfcast-view's splats do: IoU ${iou}`);
      // Mean colour off the silhouettes. Each renderer shows at a pixel a
      // convex combination of nearby surfels' stored colours (EWA: their
      // normalized Gaussian average; Cesium: the nearest point's), so over
      // the n pixels both estimate the surface's area-weighted mean colour.
      // They differ by rounding (the images' 8 bits: 0.5 level each) and by
      // sampling: nearest-point pixels vary about the smoothed ones by the
      // scan's colour spread (about 40 levels), averaged over n / 4
      // independent points (a point covers about 4 pixels here), 3 sigma of
      // which is 3 * 40 / sqrt(n / 4) = 0.7 level at n = 108,000. Hence 2.
      const mean = sum.map((s) => s.map((v) => v / n));
      for (let c = 0; c < 3; ++c)
        assert.ok(Math.abs(mean[0][c] - mean[1][c]) <= 2, `channel ${c}: CesiumJS ${mean[0][c]}, surfcast-view ${mean[1][c]}`);
      const shown = mean.map((m) => m.map((v) => v.toFixed(1)).join(","));
      t.diagnostic(`CesiumJS: ${state.tiles} tiles, IoU ${iou.toFixed(3)} with surfcast-view; mean colour over ${n} inner pixels ` +
                   `${shown[0]} against ${shown[1]}`);
    } finally {
      await browser.close();
    }
  });
});
