// surfcast-export's formats for other tools, checked by those tools, not by
// our own reader: Khronos's glTF validator on every glb; CesiumGS's
// 3d-tiles-tools traversing both tilings; glTF-Transform
// (with meshoptimizer's decoder, as CesiumJS decodes the points) and
// hand-written PLY and SPZ readers against the set as the browser client
// decodes it (format.ts, block_decode.ts, draco3d); and the consumers
// themselves in headless Chromium, from nginx on loopback: CesiumJS drawing
// the 3D Tiles (points and splats) and Spark drawing the PLY and SPZ files,
// each against surfcast-view at the same camera. The set is autzen_trim.las
// from the shared scans (colour, intensity, classification, returns, and
// its scalars); the metadata's values are also checked against a LAS file
// the test writes, whose every value it knows.

import { after, before, describe, test } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { createRequire } from "node:module";
import { existsSync, mkdtempSync, readdirSync, readFileSync, rmSync, symlinkSync, writeFileSync } from "node:fs";
import { gunzipSync } from "node:zlib";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { Logger, NodeIO } from "@gltf-transform/core";
import { EXTMeshFeatures, EXTMeshoptCompression, EXTStructuralMetadata, KHRMeshQuantization } from "@gltf-transform/extensions";
import { MeshoptDecoder } from "meshoptimizer";
import { ResourceResolvers, TilesetTraverser } from "3d-tiles-tools";
import validator from "gltf-validator";
import { PNG } from "pngjs";
import { cameraIn, coverage, fromYDown, fromYUp, launch, loadedView, settledView, startPages, toYDown, toYUp } from "./consumers.mjs";
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

let work, set, out, outRaw, implicit, splats, splatsImplicit;
let pagesUrl, browser;
// surfcast-export's default --splat-scale (export/gaussians.h).
const kSplatScale = 0.75;
// Over the Autzen scan from its south-west, as surfcast-view takes a camera.
const camera = "636300,848500,900,636590,849216,430,0,0,1,45";
// Spark draws the files of this level's cut, a quarter of the leaves'
// splats, against surfcast-view --level: SwiftShader's frames cost per splat
// (bench/RELIABILITY.md, "CI stages"). The leaves' files are checked
// against the set below, and Spark loads them too.
const sparkLevel = 1;
const children = [];

function srgbFromLinear(c) {
  return c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055;
}

// The set as the browser client reads it: tileset.json, every hierarchy
// record (following pages as the streaming client does), and a decoder for
// one surfel of a node's block.
const readSets = new Map();
function readSet(dir) {
  if (!readSets.has(dir)) readSets.set(dir, readSetOnce(dir));
  return readSets.get(dir);
}
function readSetOnce(dir) {
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

// SPZ 2 (Niantic's load-spz.cc): gzip over a header, then positions,
// opacities, colours, scales and rotations, each a column of bytes.
function readSpz(bytes) {
  const spz = gunzipSync(bytes);
  assert.equal(spz.readUInt32LE(0), 0x5053474e);
  assert.equal(spz.readUInt32LE(4), 2);
  const count = spz.readUInt32LE(8), fraction = spz[13];
  assert.equal(spz.length, 16 + 19 * count);
  const at = { position: 16, opacity: 16 + 9 * count, color: 16 + 10 * count, scale: 16 + 13 * count, rotation: 16 + 16 * count };
  return {
    count, fraction,
    get(i) {
      const [x, y, z] = [0, 1, 2].map((a) => (spz[at.rotation + 3 * i + a] - 127.5) / 127.5);
      return {
        // 24-bit fixed point with `fraction` bits.
        position: [0, 1, 2].map((a) => spz.readIntLE(at.position + 9 * i + 3 * a, 3) / 2 ** fraction),
        opacity: spz[at.opacity + i] / 255,
        // The DC coefficient at 0.15 * 255 per unit about 127.5.
        color: [0, 1, 2].map((c) => (spz[at.color + 3 * i + c] - 127.5) / (0.15 * 255) * 0.28209479177387814 + 0.5),
        // ln s at 16 per unit, offset 10.
        scales: [0, 1, 2].map((a) => Math.exp(spz[at.scale + 3 * i + a] / 16 - 10)),
        // x, y, z at 127.5 per unit about 127.5; w >= 0.
        rotation: [x, y, z, Math.sqrt(Math.max(0, 1 - x * x - y * y - z * z))],
      };
    },
  };
}
// glTF-Transform's reader, with the extensions the exports use that it
// knows: meshoptimizer's decoder (the one CesiumJS uses), the quantized
// positions and the metadata. Unlit and the Gaussian splats it does not
// know: it reads the rest of those glbs.
async function gltfReader() {
  await MeshoptDecoder.ready;
  return new NodeIO().setLogger(new Logger(Logger.Verbosity.ERROR))
    .registerExtensions([EXTMeshoptCompression, KHRMeshQuantization, EXTStructuralMetadata, EXTMeshFeatures])
    .registerDependencies({ "meshopt.decoder": MeshoptDecoder });
}
// A glb read by glTF-Transform; the Gaussian-splatting extensions, which it
// does not know (their accessors then read as zeros), left out of those required.
async function readGlb(io, file) {
  const doc = await io.binaryToJSON(new Uint8Array(readFileSync(file)));
  doc.json.extensionsRequired = (doc.json.extensionsRequired ?? []).filter((e) => !e.startsWith("KHR_gaussian_splatting"));
  return io.readJSON(doc);
}

// A double's unit in the last place at x > 0 (52 bits after the leading one).
const ulp = (x) => 2 ** (Math.floor(Math.log2(x)) - 52);
// The largest LAS intensity (a 16-bit field).
const kLasIntensityTop = 65535;

// A metadata property's value from the number stored, as the 3D Metadata
// specification defines it ("Normalized values", "Offset and scale"):
// a normalized unsigned integer divided by its type's largest value, then
// times `scale` plus `offset` (the instance's own where it gives them).
function metadataValue(classProperty, instance, stored) {
  const type = classProperty.getComponentType();
  assert.match(type, /^UINT|^FLOAT/, "the exports write unsigned integers and floats");
  const value = classProperty.getNormalized() ? stored / (2 ** Number(type.slice(4)) - 1) : stored;
  return value * (instance.getScale() ?? classProperty.getScale() ?? 1) + (instance.getOffset() ?? classProperty.getOffset() ?? 0);
}

// A primitive's metadata as glTF-Transform reads it: every property of its
// property attributes and of the property table its feature IDs point to
// (implicit feature IDs: row i is vertex i), as value(i) for vertex i.
function primitiveMetadata(doc, prim) {
  const schema = doc.getRoot().getExtension("EXT_structural_metadata").getSchema();
  const properties = {};
  for (const attributes of prim.getExtension("EXT_structural_metadata")?.listPropertyAttributes() ?? []) {
    const cls = schema.getClass(attributes.getClass());
    for (const key of attributes.listPropertyKeys()) {
      const instance = attributes.getProperty(key), accessor = prim.getAttribute(instance.getAttribute());
      properties[key] = (i) => metadataValue(cls.getProperty(key), instance, accessor.getScalar(i));
    }
  }
  for (const id of prim.getExtension("EXT_mesh_features")?.listFeatureIDs() ?? []) {
    assert.equal(id.getAttribute(), null, "implicit feature IDs");
    const table = id.getPropertyTable(), cls = schema.getClass(table.getClass());
    assert.equal(table.getCount(), prim.getAttribute("POSITION").getCount(), "a row per vertex");
    for (const key of table.listPropertyKeys()) {
      const instance = table.getProperty(key), classProperty = cls.getProperty(key);
      const bytes = instance.getValues(), view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
      const type = classProperty.getComponentType(), size = Number(type.replace(/\D/g, "")) / 8;
      assert.equal(bytes.length, size * table.getCount(), `${key}: a ${type} a row`);
      const read = { UINT8: (o) => view.getUint8(o), UINT16: (o) => view.getUint16(o, true), UINT32: (o) => view.getUint32(o, true),
                     UINT64: (o) => Number(view.getBigUint64(o, true)), FLOAT32: (o) => view.getFloat32(o, true),
                     FLOAT64: (o) => view.getFloat64(o, true) }[type];
      properties[key] = (i) => metadataValue(classProperty, instance, read(i * size));
    }
  }
  return properties;
}

describe("exports, as their consumers read them", { skip }, () => {
  before(() => {
    assert.ok(existsSync(scan), `${scan}: the shared scans are needed (SURFCAST_DATA_DIR)`);
    work = mkdtempSync(join(tmpdir(), "surfcast-exports-"));
    set = join(work, "autzen");
    out = join(work, "autzen3d");
    execFileSync(bin("surfcast-build"), ["-q", scan, "--attributes", "all", "-o", set]);
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "--as", "points", "-q", "-o", out]);  // meshopt: the default
    outRaw = join(work, "autzen3d-raw");
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "--as", "points", "--compression", "none", "-q", "-o", outRaw]);
    implicit = join(work, "autzen3d-implicit");
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "--as", "points", "--tiling", "implicit", "-q", "-o", implicit]);
    splats = join(work, "autzen-splats");
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "-q", "-o", splats]);  // splats: the default
    splatsImplicit = join(work, "autzen-splats-implicit");
    execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "--tiling", "implicit", "-q", "-o", splatsImplicit]);
    for (const f of ["ply", "spz"]) {
      execFileSync(bin("surfcast-export"), [set, "--format", f, "-q", "-o", join(work, `autzen.${f}`)]);
      execFileSync(bin("surfcast-export"), [set, "--format", f, "--level", String(sparkLevel), "-q", "-o", join(work, `autzen-level.${f}`)]);
    }
  });
  after(async () => {
    await browser?.close();
    for (const c of children) c.kill();
    if (work) rmSync(work, { recursive: true, force: true });
  });

  // The validator does not decode EXT_meshopt_compression (it reports it
  // as unsupported): it checks the compressed points' structure, and the
  // uncompressed export's data too, which the round trip shows the
  // compressed one decodes to.
  test("Khronos's glTF validator: no errors or warnings in any glb", async (t) => {
    const infos = new Set();
    for (const dir of [out, outRaw, splats]) {
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

  test("tileset.json: one tile per node, REPLACE, errors from h, boxes nested and holding their surfels", async () => {
    const { info, nodes } = readSet(set);
    const decode = await decoderFor(info);
    const centre = info.boundsMin.map((m, a) => (m + info.boundsMax[a]) / 2);
    for (const dir of [out, outRaw, splats]) {
      const tileset = JSON.parse(readFileSync(join(dir, "tileset.json"), "utf8"));
      assert.equal(tileset.asset.version, "1.1");
      assert.equal(tileset.root.refine, "REPLACE");
      assert.deepEqual(tileset.root.transform.slice(12, 15), centre, "the root carries the set's centre");
      let tiles = 0;
      const inside = (c, p) => [0, 1, 2].every((a) => c.box[a] - c.box[3 + 4 * a] >= p.box[a] - p.box[3 + 4 * a] - 1e-9 &&
                                                        c.box[a] + c.box[3 + 4 * a] <= p.box[a] + p.box[3 + 4 * a] + 1e-9);
      const walk = (tile, key, parent) => {
        ++tiles;
        const n = nodes.get(key);
        assert.ok(n, `tile ${key} has a node`);
        assert.equal(tile.content?.uri, `tiles/${key}.glb`);
        assert.ok(existsSync(join(dir, tile.content.uri)));
        // A node's error is its spacing h, the distance its samples lie apart (leaves too).
        assert.ok(Math.abs(tile.geometricError - n.spacing) <= 1e-6 * n.spacing, `tile ${key}'s error`);
        if (parent) assert.ok(inside(tile.boundingVolume, parent.boundingVolume), `tile ${key} lies inside its parent`);
        // Its surfels (a sample, as the browser decodes them) lie in its box (root frame: less the centre).
        const box = tile.boundingVolume.box;
        for (let i = 0; i < n.surfelCount; i += Math.max(1, Math.floor(n.surfelCount / 20))) {
          const p = decode(n, i).position;
          for (let a = 0; a < 3; ++a)
            assert.ok(Math.abs(p[a] - centre[a] - box[a]) <= box[3 + 4 * a] + 1e-9, `tile ${key}: surfel ${i} outside its box`);
        }
        const kids = tile.children ?? [];
        assert.equal(kids.length, [...Array(8).keys()].filter((c) => n.childMask & (1 << c)).length);
        let c = 0;
        for (let i = 0; i < 8; ++i) if (n.childMask & (1 << i)) walk(kids[c++], format.childKey(n, i), tile);
      };
      walk(tileset.root, "0-0-0-0", null);
      assert.equal(tiles, nodes.size);
    }
  });

  // The tree as CesiumGS's 3d-tiles-tools traverses it (the 3D Tiles
  // validator, 3d-tiles-validator, is missing from the registry these
  // machines reach): explicit tiles as they stand, an
  // implicit tileset's tiles from its subtree files, each tile's box and
  // error from its metadata where its semantics say (TILE_BOUNDING_BOX,
  // TILE_GEOMETRIC_ERROR). Returns the tiles (the implicit root's
  // placeholder left out) as [content uri or "", box, error].
  async function traverse(dir) {
    const tileset = JSON.parse(readFileSync(join(dir, "tileset.json"), "utf8"));
    const traverser = new TilesetTraverser(dir, ResourceResolvers.createFileResourceResolver(dir), { depthFirst: true });
    const tiles = [];
    await traverser.traverse(tileset, async (tile) => {
      if (tile.isImplicitTilesetRoot()) return true;
      const t = tile.asFinalTile();
      tiles.push([t.content?.uri ?? "", t.boundingVolume.box, t.geometricError]);
      return true;
    });
    const key = (t) => JSON.stringify(t);  // content-less tiles: by box and error too
    return tiles.sort((a, b) => (key(a) < key(b) ? -1 : key(a) > key(b) ? 1 : 0));
  }

  // Both kinds of content. CesiumJS draws the implicit points below; an
  // implicit splat export's tiles are the explicit one's files, which it draws too.
  test("implicit tiling: 3d-tiles-tools finds the explicit tileset's tiles, boxes and errors in the subtrees", async () => {
    const { info, nodes } = readSet(set);
    const t = JSON.parse(readFileSync(join(implicit, "tileset.json"), "utf8"));
    const explicitRoot = JSON.parse(readFileSync(join(out, "tileset.json"), "utf8")).root;
    assert.deepEqual(t.root.transform, explicitRoot.transform);
    assert.equal(t.root.refine, "REPLACE");
    assert.equal(t.root.implicitTiling.subdivisionScheme, "OCTREE");
    assert.equal(t.root.implicitTiling.availableLevels, Math.max(...[...nodes.values()].map((n) => n.level)) + 1);
    // The root box is the set's root cube, which implicit tiling divides.
    const edge = format.nodeEdge(info, 0), origin = t.root.transform.slice(12, 15);
    const min = format.nodeMin(info, nodes.get("0-0-0-0"));
    assert.deepEqual(t.root.boundingVolume.box, [0, 1, 2].map((a) => min[a] + edge / 2 - origin[a])
      .concat([edge / 2, 0, 0, 0, edge / 2, 0, 0, 0, edge / 2]));
    for (const [explicitDir, implicitDir] of [[out, implicit], [splats, splatsImplicit]]) {
      const [a, b] = [explicitDir, implicitDir].map((d) => JSON.parse(readFileSync(join(d, "tileset.json"), "utf8")));
      for (const k of ["asset", "extensionsUsed", "extensionsRequired", "extensions", "geometricError"]) assert.deepEqual(b[k], a[k], k);
      const [explicitTiles, implicitTiles] = [await traverse(explicitDir), await traverse(implicitDir)];
      assert.equal(explicitTiles.length, nodes.size);
      assert.ok(readdirSync(join(implicitDir, "subtrees")).length > 1, "the tree spans more than one subtree");
      assert.deepEqual(implicitTiles, explicitTiles);
      for (const f of readdirSync(join(explicitDir, "tiles")))
        assert.ok(readFileSync(join(explicitDir, "tiles", f)).equals(readFileSync(join(implicitDir, "tiles", f))), `${f}: the same tile`);
    }
  });

  // Octahedral normals at 8 bits (meshopt's filter, then 8-bit components):
  // an octahedral coordinate rounds by half a cell of 1/127, at most
  // sqrt(2)/254 across; the octahedron's point moves by at most sqrt(3)
  // times that (z = 1 - |u| - |v|) and its direction by sqrt(3) times more
  // (|p| >= 1/sqrt(3)): 3 sqrt(2)/254 rad. Each decoded component then
  // rounds to 1/127, at most sqrt(3)/254 more.
  const kNormalTurn = (3 * Math.SQRT2 + Math.sqrt(3)) / 254;

  test("round trip: glTF-Transform reads back the set's surfels, and the compressed points decode to the uncompressed ones", async (t) => {
    const { info, nodes } = readSet(set);
    const decode = await decoderFor(info);
    const tileset = JSON.parse(readFileSync(join(out, "tileset.json"), "utf8"));
    assert.deepEqual(tileset.extensions["3DTILES_content_gltf"].extensionsRequired, ["KHR_mesh_quantization", "EXT_meshopt_compression"]);
    const origin = tileset.root.transform.slice(12, 15);
    const io = await gltfReader();
    let compared = 0, worst = 0, worstTurn = 0;
    for (const n of nodes.values()) {
      const doc = await io.readBinary(new Uint8Array(readFileSync(join(out, "tiles", `${n.key}.glb`))));
      const raw = await io.readBinary(new Uint8Array(readFileSync(join(outRaw, "tiles", `${n.key}.glb`))));
      const node = doc.getRoot().listNodes()[0];
      const prim = doc.getRoot().listMeshes()[0].listPrimitives()[0];
      const rawPrim = raw.getRoot().listMeshes()[0].listPrimitives()[0];
      assert.deepEqual(rawPrim.listSemantics(), prim.listSemantics());
      // Exactly, but for the normals: meshoptimizer's octahedral filter
      // rounds by a step differently from one version to another.
      for (const semantic of prim.listSemantics()) {
        const [a, b] = [prim, rawPrim].map((p) => p.getAttribute(semantic).getArray());
        if (semantic === "NORMAL") assert.ok(a.length === b.length && a.every((v, i) => Math.abs(v - b[i]) <= 1), `node ${n.key}'s normals`);
        else assert.deepEqual(a, b, `node ${n.key}'s ${semantic}`);
      }
      assert.deepEqual(raw.getRoot().listNodes()[0].getMatrix(), node.getMatrix());
      const position = prim.getAttribute("POSITION"), normal = prim.getAttribute("NORMAL"), color = prim.getAttribute("COLOR_0");
      assert.equal(position.getCount(), n.surfelCount, `node ${n.key}'s point count`);
      const m = node.getMatrix();
      const edge = format.nodeEdge(info, n.level);
      const metadata = primitiveMetadata(doc, prim);
      // The block's own integers scaled by the node's matrix: rounding only.
      const tolerance = 1e-9 * edge;
      const step = Math.max(1, Math.floor(n.surfelCount / 40));
      for (let i = 0; i < n.surfelCount; i += step) {
        const s = decode(n, i);
        const p = position.getElement(i, []);
        const q = [0, 1, 2].map((r) => m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]);
        // glTF is y-up: (x, y, z) of the set is (x, z, -y) in the glb.
        const world = fromYUp(q).map((v, a) => v + origin[a]);
        for (let a = 0; a < 3; ++a) {
          worst = Math.max(worst, Math.abs(world[a] - s.position[a]) / edge);
          assert.ok(Math.abs(world[a] - s.position[a]) <= tolerance, `node ${n.key} surfel ${i} axis ${a}: ${world[a]} vs ${s.position[a]}`);
        }
        // The block's normal, made unit, within the 8-bit octahedral rounding
        // (turned by the node's matrix as glTF turns normals; its scale is uniform).
        const v = normal.getElement(i, []);
        const g = fromYUp([0, 1, 2].map((r) => m[r] * v[0] + m[4 + r] * v[1] + m[8 + r] * v[2]));
        const len = Math.hypot(...s.normal) * Math.hypot(...g);
        const turn = Math.acos(Math.min(1, (g[0] * s.normal[0] + g[1] * s.normal[1] + g[2] * s.normal[2]) / len));
        worstTurn = Math.max(worstTurn, turn);
        assert.ok(turn <= kNormalTurn, `node ${n.key} surfel ${i}'s normal is ${turn} rad off`);
        // COLOR_0 is linear (glTF's definition) at 16 bits: back to the set's 8-bit sRGB exactly.
        const c = color.getElement(i, []);
        for (let k = 0; k < 3; ++k) assert.equal(Math.round(srgbFromLinear(c[k]) * 255), Math.round(s.color[k] * 255));
        assert.equal(c[3], 1);
        expectSetValues(info, metadata, s, i, `node ${n.key} surfel ${i}`);
        ++compared;
      }
    }
    const bytes = (dir) => readdirSync(join(dir, "tiles")).reduce((sum, f) => sum + readFileSync(join(dir, "tiles", f)).length, 0);
    t.diagnostic(`${compared} surfels compared; largest position error ${(worst * 1e9).toFixed(3)} billionths of a node's edge, ` +
                 `normal ${worstTurn.toFixed(4)} rad (bound ${kNormalTurn.toFixed(4)}); glbs ${bytes(out)} bytes, uncompressed ${bytes(outRaw)}`);
  });

  // The metadata of a tile's surfel (primitiveMetadata) against surfel s as
  // the browser client decodes it: every attribute after the fixed ones
  // (LiDAR, scalars) but the opacity (COLOR_0's alpha), as its value,
  // value = stored · scale + offset (docs/FORMAT.md). Intensity is a 16-bit
  // LAS value: the top step's value can pass 65535 by rounding, which the
  // export clamps (as the LAS export does). Continuous scalars come through
  // the metadata's normalized integers, offset and scale in doubles: a few
  // of a double's ulps of the terms' largest sum.
  // A wide field's low part, "<name>:low" (docs/FORMAT.md, "Scalar
  // attributes"), adds low · its scale to its top part's value.
  function expectSetValues(info, metadata, s, i, what) {
    const attribute = (name) => info.attributes.find((a) => a.name === name);
    const names = info.attributes.filter((a) => !format.kFixedAttributes.includes(a.name) && a.name !== "opacity" &&
                                                !(a.name.endsWith(":low") && attribute(a.name.slice(0, -":low".length))));
    assert.deepEqual(Object.keys(metadata).sort(), names.map((a) => a.name).sort(), `${what}: every attribute`);
    for (const a of names) {
      const low = attribute(`${a.name}:low`);
      const stored = s.raw[a.name] * a.scale + a.offset + (low ? s.raw[low.name] * low.scale : 0);
      const value = a.name === "intensity" ? Math.min(kLasIntensityTop, stored) : stored;
      const rounding = a.kind === "continuous" && a.name !== "intensity"
        ? 4 * ulp(Math.abs(a.offset) + Math.abs(a.scale) * 2 ** Number(a.type.slice(4))) : 0;
      assert.ok(Math.abs(metadata[a.name](i) - value) <= rounding,
                `${what}'s ${a.name}: ${metadata[a.name](i)}, the set's value ${value} (stored ${s.raw[a.name]})`);
    }
  }

  // A block decoder for node n of the set, as the browser client decodes it.
  async function decoderFor(info) {
    const draco = await createRequire(import.meta.url)("draco3d").createDecoderModule({});
    const blob = readFileSync(join(set, "blocks.bin"));
    const coloring = { by: "rgb", originZ: 0, elevationMin: 0, elevationMax: 1, intensityScale: 1, intensityOffset: 0,
                       intensityP2: 0, intensityP98: 1, hiddenClasses: [] };
    return (n, i) => blocks.decodeBlock(draco, {
      id: 1, key: n.key, blob: blob.buffer.slice(blob.byteOffset + n.blockOffset, blob.byteOffset + n.blockOffset + n.blockSize),
      crc: n.blockCrc, points: n.surfelCount, positionBits: n.positionBits, min: format.nodeMin(info, n), edge: format.nodeEdge(info, n.level),
      spacing: n.spacing, hasRadius: !!(n.flags & format.kFlagHasRadius), hasEdgeWeights: !!(n.flags & format.kFlagEdgeWeights),
      colorBits: info.colorBits, weights: info.weights !== "none", ...format.blockLayout(info), coloring, pick: i }).picked;
  }

  // One Gaussian read back against surfel s: where it is (set coordinates,
  // within `near`), its colour (within `colorStep`), its standard
  // deviations (kSplatScale times kernel scale times radius in the plane, 1 % of it along the
  // normal; within a factor e^logStep) and the rotation taking z to the
  // normal (quaternion x, y, z, w in the file's axes `axes`, within `turn`
  // radians). Returns nothing; asserts.
  function expectGaussian(g, s, info, { near, colorStep, logStep, turn, axes, what }) {
    for (let a = 0; a < 3; ++a) assert.ok(Math.abs(g.position[a] - s.position[a]) <= near, `${what}: axis ${a}, ${g.position[a]} vs ${s.position[a]}`);
    for (let c = 0; c < 3; ++c) assert.ok(Math.abs(g.color[c] - s.color[c]) <= colorStep, `${what}: colour ${c}, ${g.color[c]} vs ${s.color[c]}`);
    const sigma = kSplatScale * info.kernelScale * s.radius;
    for (const [a, want] of [[0, sigma], [1, sigma], [2, 0.01 * sigma]])
      assert.ok(Math.abs(Math.log(g.scales[a] / want)) <= logStep, `${what}: scale ${a}, ${g.scales[a]} vs ${want}`);
    const [x, y, z, w] = g.rotation;
    const nz = axes([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]);
    const len = Math.hypot(...s.normal);
    const cos = (nz[0] * s.normal[0] + nz[1] * s.normal[1] + nz[2] * s.normal[2]) / len;
    assert.ok(Math.acos(Math.min(1, cos)) <= turn(g), `${what}: the normal off by ${Math.acos(Math.min(1, cos))} rad (bound ${turn(g)}, rotation ${g.rotation}, normal ${s.normal})`);
  }

  // SPZ's byte steps: a colour byte is 1 / (0.15 * 255) of the DC coefficient;
  // a scale byte 1/16 of its log; each of x, y, z rounds by up to d = 1/255
  // and w = sqrt(1 - x² - y² - z²) follows: w² moves by at most
  // s = 2 d (|x| + |y| + |z|) + 3 d², so w by at most s / (w + sqrt(w² - s))
  // (to first order (|x| + |y| + |z|) d / w, which a small w outgrows); a
  // quaternion off by e turns a vector by at most 2e (plus the block's own
  // normal rounding).
  const spzColorStep = 0.5 / (0.15 * 255) * 0.28209479177387814 + 1e-9;
  const spzTurn = (g) => {
    const [x, y, z, w] = g.rotation, d = 1 / 255;
    const s = 2 * d * (Math.abs(x) + Math.abs(y) + Math.abs(z)) + 3 * d * d;
    const dw = w * w > s ? s / (w + Math.sqrt(w * w - s)) : Math.sqrt(w * w + s);
    return 2 * Math.hypot(d, d, d, dw) + 1e-3;
  };

  test("round trip: the 3D Tiles splats' SPZ holds the set's surfels as Gaussians, their attributes' values a property table", async (t) => {
    const { info, nodes } = readSet(set);
    const decode = await decoderFor(info);
    const io = await gltfReader();
    const tileset = JSON.parse(readFileSync(join(splats, "tileset.json"), "utf8"));
    assert.deepEqual(tileset.extensionsRequired, ["3DTILES_content_gltf"]);
    assert.deepEqual(tileset.extensions["3DTILES_content_gltf"].extensionsRequired,
                     ["KHR_gaussian_splatting", "KHR_gaussian_splatting_compression_spz_2"]);
    const origin = tileset.root.transform.slice(12, 15);
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
      const spz = readSpz(bin.subarray(view.byteOffset, view.byteOffset + view.byteLength));
      assert.equal(spz.count, n.surfelCount);
      assert.equal(gltf.accessors[prim.attributes.POSITION].count, spz.count);
      const m = gltf.nodes[0].matrix;
      const edge = format.nodeEdge(info, n.level);
      // The attributes: a property table whose rows are the splats'
      // implicit feature IDs, their vertex indices (EXT_mesh_features), as
      // glTF-Transform reads it.
      assert.deepEqual(prim.extensions.EXT_mesh_features.featureIds, [{ featureCount: spz.count, propertyTable: 0 }]);
      const doc = await readGlb(io, join(splats, "tiles", `${n.key}.glb`));
      const metadata = primitiveMetadata(doc, doc.getRoot().listMeshes()[0].listPrimitives()[0]);
      for (let i = 0; i < spz.count; i += Math.max(1, Math.floor(spz.count / 40))) {
        const g = spz.get(i), surfel = decode(n, i);
        assert.equal(g.opacity, 1, "opaque");
        expectSetValues(info, metadata, surfel, i, `node ${n.key} splat ${i}`);
        const p = fromYUp([0, 1, 2].map((a) => g.position[a] + m[12 + a]));
        g.position = p.map((v, a) => v + origin[a]);
        expectGaussian(g, surfel, info, { near: 2 ** -spz.fraction / 2 + 1e-6 * edge, colorStep: spzColorStep, logStep: 1 / 32 + 1e-6,
                                          turn: spzTurn, axes: fromYUp, what: `node ${n.key} surfel ${i}` });
        ++compared;
      }
    }
    t.diagnostic(`${compared} splats compared`);
  });

  test("round trip: the PLY and SPZ files hold the leaves' surfels as Gaussians, node by node in key order", async (t) => {
    const { info, nodes } = readSet(set);
    const decode = await decoderFor(info);
    const origin = info.boundsMin.map((m, a) => (m + info.boundsMax[a]) / 2);
    const extent = Math.max(...info.boundsMax.map((m, a) => m - info.boundsMin[a]));
    const key = (n) => [n.level, n.x, n.y, n.z];
    const leaves = [...nodes.values()].filter((n) => n.childMask === 0 && n.surfelCount > 0)
      .sort((a, b) => { const [p, q] = [key(a), key(b)]; for (let k = 0; k < 4; ++k) if (p[k] !== q[k]) return p[k] - q[k]; return 0; });
    const total = leaves.reduce((s, n) => s + n.surfelCount, 0);

    // The PLY: its header as the reference implementation writes it, then 17 floats a Gaussian.
    const ply = readFileSync(join(work, "autzen.ply"));
    const end = ply.indexOf("end_header\n") + "end_header\n".length;
    const header = ply.subarray(0, end).toString();
    assert.match(header, new RegExp(`^ply\nformat binary_little_endian 1.0\n(comment .*\n)*element vertex ${total}\n`));
    const names = [...header.matchAll(/property float (\w+)/g)].map((m) => m[1]);
    assert.deepEqual(names, ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                             "rot_0", "rot_1", "rot_2", "rot_3"]);
    assert.equal(ply.length, end + 68 * total);
    const spz = readSpz(readFileSync(join(work, "autzen.spz")));
    assert.equal(spz.count, total);
    let record = 0, compared = 0;
    for (const n of leaves) {
      for (let i = 0; i < n.surfelCount; i += Math.max(1, Math.floor(n.surfelCount / 40))) {
        const s = decode(n, i);
        const f = (k) => ply.readFloatLE(end + 68 * (record + i) + 4 * k);
        const g = {
          position: fromYDown([f(0), f(1), f(2)]).map((v, a) => v + origin[a]),
          color: [6, 7, 8].map((k) => f(k) * 0.28209479177387814 + 0.5),
          scales: [10, 11, 12].map((k) => Math.exp(f(k))),
          rotation: [f(14), f(15), f(16), f(13)],
        };
        // Opacity as a logit: opaque is 0.999.
        assert.ok(Math.abs(1 / (1 + Math.exp(-f(9))) - 0.999) < 1e-6);
        // Floats: the angle from acos(cos) near 1 has the square root of float's rounding (about 5e-4 rad).
        expectGaussian(g, s, info, { near: 1e-6 * extent, colorStep: 1e-6, logStep: 1e-5, turn: () => 1e-3, axes: fromYDown,
                                     what: `PLY node ${n.key} surfel ${i}` });
        const z = spz.get(record + i);
        z.position = fromYUp(z.position).map((v, a) => v + origin[a]);
        expectGaussian(z, s, info, { near: 2 ** -spz.fraction / 2 + 1e-6 * extent, colorStep: spzColorStep, logStep: 1 / 32 + 1e-6,
                                     turn: spzTurn, axes: fromYUp, what: `SPZ node ${n.key} surfel ${i}` });
        ++compared;
      }
      record += n.surfelCount;
    }
    t.diagnostic(`${compared} of ${total} splats compared in each file`);
  });

  // The consumers' pages (test/consumers.mjs), started on first use.
  async function pages() {
    if (!pagesUrl) {
      pagesUrl = await startPages(work, join(work, "www"), children);
      symlinkSync(work, join(work, "www", "sets"));
      browser = await launch(chromium);
    }
    return pagesUrl;
  }

  // The set's leaves' surfels: what a splat file of the leaves holds.
  const leafSurfels = () => [...readSet(set).nodes.values()].reduce((sum, n) => sum + (n.childMask ? 0 : n.surfelCount), 0);

  // Spark's view of a splat file under work/, at the test's camera in the
  // file's axes; or, `loadOnly`, its state once the file is loaded.
  async function spark(file, axes, loadOnly = false) {
    const { info } = readSet(set);
    const origin = info.boundsMin.map((m, a) => (m + info.boundsMax[a]) / 2);
    const url = `${await pages()}/spark.html?splats=sets/${file}&camera=${cameraIn(camera, origin, axes)}`;
    if (loadOnly) return loadedView(browser, url, "window.sparkState");
    // Spark sorts in a worker as it draws: a few frames settle it.
    return settledView(browser, url, "window.sparkState", 3);
  }

  // CesiumJS's view of an export (a folder under work/) at the test's camera.
  async function cesium(folder, params, splats) {
    // Tiles load before they are drawn, and splats are drawn sorted first
    // from their snapshot, then sorted again while the camera rests: 30
    // frames after the last tile loaded (about 20 s in SwiftShader: the first
    // frames, before the splats are drawn, take milliseconds, the later ones
    // 1-2 s) the view has settled in every run seen. Points are drawn as
    // they will stay from the first frame after loading (the same pixels and
    // colours from frame 1 to 36 in every run probed: bench/RELIABILITY.md,
    // "CI stages"), so settledView's two images two frames apart suffice.
    const url = await pages();
    return settledView(browser, `${url}/cesium.html?tileset=sets/${folder}/tileset.json&camera=${camera}${params}`, "window.cesiumState",
                       splats ? 30 : 1);
  }

  // surfcast-view at the same camera, on the same black: every leaf, or the
  // cut `level` draws (--level).
  const references = new Map();
  function surfcastView(level = "leaves") {
    if (!references.has(level)) {
      const file = join(work, `surfcast-view-${level}.png`);
      execFileSync(bin("surfcast-view"), ["--headless", set, "--camera", camera, "--size", "640x480", "--background", "0,0,0",
                                          "--level", String(level), "--out", file], { stdio: "ignore" });
      references.set(level, PNG.sync.read(readFileSync(file)));
    }
    return references.get(level);
  }

  // How `png` covers the pixels surfcast-view's image does, and the mean
  // colours of both over the pixels off either's silhouette.
  function compare(png, level) {
    const want = surfcastView(level);
    // Pixels whose four neighbours are covered too: off the silhouette.
    const inner = (m) => m.map((v, i) => v && m[i - 1] && m[i + 1] && m[i - 640] && m[i + 640] ? 1 : 0);
    const a = coverage(png), b = coverage(want), ai = inner(a), bi = inner(b);
    let both = 0, either = 0, n = 0;
    const sum = [[0, 0, 0], [0, 0, 0]], squares = [0, 0, 0];
    for (let i = 0; i < a.length; ++i) {
      both += a[i] & b[i];
      either += a[i] | b[i];
      if (!(ai[i] && bi[i])) continue;
      ++n;
      for (let c = 0; c < 3; ++c) {
        sum[0][c] += png.data[4 * i + c], sum[1][c] += want.data[4 * i + c];
        squares[c] += want.data[4 * i + c] ** 2;
      }
    }
    const [mine, theirs] = sum.map((s) => s.map((v) => v / n));
    // The reference's colour spread over those pixels, its largest channel's.
    const spread = Math.max(...theirs.map((m, c) => Math.sqrt(Math.max(0, squares[c] / n - m * m))));
    return { iou: both / either, n, mine, theirs, spread,
             shown: `${mine.map((v) => v.toFixed(1))} against ${theirs.map((v) => v.toFixed(1))}` };
  }

  // Mean colour off the silhouettes. Each renderer shows at a pixel a convex
  // combination of nearby surfels' stored colours (EWA: their normalized
  // Gaussian average; Cesium's points: the nearest one's; the splats: a
  // front-to-back blend), so over the n pixels both estimate the surface's
  // area-weighted mean colour. They differ by rounding (the images' 8 bits:
  // 0.5 level each; SPZ's colour bytes: up to 1 level more) and by sampling:
  // a pixel varies about the smoothed one by the scene's colour spread
  // (measured on the reference), averaged over n / k independent surfels (a
  // leaf's surfel covers about k = 4 pixels at this camera, a coarser cut's
  // as many more as it has fewer surfels): 3 sigma of that mean.
  function expectSameColours(result, spz, k) {
    const tolerance = 1 + (spz ? 1 : 0) + (3 * result.spread) / Math.sqrt(result.n / k);
    for (let c = 0; c < 3; ++c)
      assert.ok(Math.abs(result.mine[c] - result.theirs[c]) <= tolerance,
                `channel ${c}: ${result.shown} (tolerance ${tolerance.toFixed(2)}, spread ${result.spread.toFixed(1)})`);
    return tolerance;
  }

  // A consumer's settled view against surfcast-view's of the same cut (the
  // leaves, or a level with `surfels` of them): no errors, the pixels covered
  // (IoU at least 0.8) and the colours (expectSameColours).
  function expectLikeSurfcastView(t, what, { state, png, problems }, spz, level = "leaves", surfels = 0) {
    assert.deepEqual(state.errors, []);
    assert.deepEqual(problems, []);
    const r = compare(png, level);
    assert.ok(r.iou >= 0.8, `${what} covers the pixels surfcast-view's splats do: IoU ${r.iou}`);
    const tolerance = expectSameColours(r, spz, 4 * (surfels ? leafSurfels() / surfels : 1));
    t.diagnostic(`${what}: IoU ${r.iou.toFixed(3)} with surfcast-view; mean colour over ${r.n} inner pixels ${r.shown} ` +
                 `(tolerance ${tolerance.toFixed(2)})`);
  }

  for (const [folder, params, what] of [
    // Points sized by their tile's error, and no multisampling: a pixel
    // shows one point's colour, not a blend with the background.
    ["autzen3d", "&attenuation=1&msaa=1", "points"],
    ["autzen3d-implicit", "&attenuation=1&msaa=1", "points tiled implicitly"],
    ["autzen-splats", "", "splats"],
  ])
    test(`CesiumJS draws the ${what} where surfcast-view draws the set, in its colours`,
         { skip: chromium ? false : "Chromium is missing" }, async (t) => {
      const view = await cesium(folder, params, what === "splats");
      assert.ok(view.state.tiles >= 1, `${view.state.tiles} tiles loaded`);
      expectLikeSurfcastView(t, `CesiumJS's ${what} (${view.state.tiles} tiles)`, view, what === "splats");
    });

  for (const [file, axes, what] of [["autzen.ply", toYDown, "PLY"], ["autzen.spz", toYUp, "SPZ"]])
    test(`Spark loads the ${what} file of the leaves, every splat`, { skip: chromium ? false : "Chromium is missing" }, async () => {
      const { state, problems } = await spark(file, axes, true);
      assert.deepEqual(state.errors, []);
      assert.deepEqual(problems, []);
      assert.equal(state.splats, leafSurfels(), "the leaves' surfels");
    });

  for (const [file, axes, what] of [["autzen-level.ply", toYDown, "PLY"], ["autzen-level.spz", toYUp, "SPZ"]])
    test(`Spark draws the ${what} file's splats where surfcast-view draws the set's level ${sparkLevel}, in its colours`,
         { skip: chromium ? false : "Chromium is missing" }, async (t) => {
      const view = await spark(file, axes);
      // The cut: the level's nodes and the leaves above it.
      const cut = [...readSet(set).nodes.values()].filter((n) => n.level === sparkLevel || (n.level < sparkLevel && !n.childMask));
      const surfels = cut.reduce((sum, n) => sum + n.surfelCount, 0);
      assert.equal(view.state.splats, surfels, `level ${sparkLevel}'s cut`);
      expectLikeSurfcastView(t, `Spark's ${what} file of level ${sparkLevel}`, view, what === "SPZ", sparkLevel, surfels);
    });
});

// The exports give values, never the set's storage codes (docs/EXPORT.md,
// "Metadata"), on a LAS file written here, so that every input value is
// known: a grid of points whose intensities span 1000..60000, GPS times
// about 4·10^8 s, user data 10..20, two classes, and one return of one, one
// point source ID and no scan angle or flags throughout. Two sets of it: by
// default (intensity kept as (value − 1000) / a step of 16, docs/FORMAT.md;
// the returns the set's constants), and with --attributes all (GPS time
// kept less its minimum; user data, categorical, less its minimum; the point
// source ID, scan angle and flags the set's constants).
describe("3D Tiles metadata holds the input's values, as glTF-Transform reads it", () => {
  const kSide = 200;            // points per grid row and column
  const kSpacing = 5;           // grid step in LAS units (0.05 m at the file's 0.01 scale)
  const kLasScale = 0.01;
  const kIntensityMin = 1000, kIntensityMax = 60000;
  const kGpsStart = 4e8, kGpsStep = 0.000617;  // seconds (adjusted standard GPS time)
  const kPointSourceId = 7;
  const count = kSide * kSide;
  // Point i: its grid cell, and values spread over the grid (7919, a prime,
  // not a factor of the count, visits every value once).
  const input = [...Array(count).keys()].map((i) => {
    const spread = (i * 7919) % count;
    return { ix: i % kSide, iy: Math.floor(i / kSide),
             intensity: kIntensityMin + Math.round((spread * (kIntensityMax - kIntensityMin)) / (count - 1)),
             classification: i % 5 === 0 ? 6 : 2, user_data: 10 + (spread % 11), gps_time: kGpsStart + i * kGpsStep,
             return_number: 1, number_of_returns: 1 };
  });
  // The dimensions every point has the same value of.
  const kOneValue = { return_number: 1, number_of_returns: 1, point_source_id: kPointSourceId, scan_angle: 0, classification_flags: 0,
                      scan_direction_flag: 0, edge_of_flight_line: 0 };
  // The sets' build options, the attributes each keeps in its blocks, and
  // its constants (tileset.json's "constants": one value over the set).
  const sets = {
    quantized: { args: [], kept: ["classification", "intensity"], constants: ["number_of_returns", "return_number"] },
    all: { args: ["--attributes", "all"], kept: ["classification", "gps_time", "intensity", "number_of_returns", "return_number", "user_data"],
           constants: ["classification_flags", "edge_of_flight_line", "point_source_id", "scan_angle", "scan_direction_flag"] },
  };
  const exports = { points: ["--as", "points"], "points-implicit": ["--as", "points", "--tiling", "implicit"], splats: [],
                    "splats-implicit": ["--tiling", "implicit"] };
  let work;

  // LAS 1.2, point data record format 1 (ASPRS LAS 1.2: a 227-byte header, no
  // VLRs, 28-byte records with GPS time); a gently rolling surface.
  function writeLas(path) {
    const kHeader = 227, kRecord = 28;
    const b = Buffer.alloc(kHeader + kRecord * count);
    b.write("LASF", 0);
    b.writeUInt16LE(1, 6);  // global encoding: adjusted standard GPS time
    b[24] = 1, b[25] = 2;
    b.writeUInt16LE(kHeader, 94);
    b.writeUInt32LE(kHeader, 96);
    b[104] = 1;
    b.writeUInt16LE(kRecord, 105);
    b.writeUInt32LE(count, 107);
    b.writeUInt32LE(count, 111);  // all first returns
    const z = (p) => Math.round(100 * Math.sin(p.ix / 15) * Math.cos(p.iy / 20));
    for (let a = 0; a < 3; ++a) b.writeDoubleLE(kLasScale, 131 + 8 * a);
    const extent = kSpacing * (kSide - 1) * kLasScale;
    for (const [at, v] of [[179, extent], [187, 0], [195, extent], [203, 0], [211, Math.max(...input.map(z)) * kLasScale],
                           [219, Math.min(...input.map(z)) * kLasScale]])
      b.writeDoubleLE(v, at);
    input.forEach((p, i) => {
      const r = kHeader + kRecord * i;
      b.writeInt32LE(p.ix * kSpacing, r), b.writeInt32LE(p.iy * kSpacing, r + 4), b.writeInt32LE(z(p), r + 8);
      b.writeUInt16LE(p.intensity, r + 12);
      b[r + 14] = 1 | (1 << 3);  // return 1 of 1
      b[r + 15] = p.classification, b[r + 17] = p.user_data;
      b.writeUInt16LE(kPointSourceId, r + 18);
      b.writeDoubleLE(p.gps_time, r + 20);
    });
    writeFileSync(path, b);
  }

  before(() => {
    work = mkdtempSync(join(tmpdir(), "surfcast-values-"));
    writeLas(join(work, "values.las"));
    for (const [name, { args }] of Object.entries(sets)) {
      const set = join(work, name);
      execFileSync(bin("surfcast-build"), ["-q", join(work, "values.las"), ...args, "-o", set]);
      for (const [dir, options] of Object.entries(exports))
        execFileSync(bin("surfcast-export"), [set, "--format", "3dtiles", "-q", "-o", join(work, `${name}-${dir}`), ...options]);
    }
  });
  after(() => {
    if (work) rmSync(work, { recursive: true, force: true });
  });

  // The leaves' tiles, which hold the input points (docs/FORMAT.md), from
  // an explicit tileset.json: tiles without children.
  function leafTiles(dir) {
    const leaves = [];
    const walk = (tile) => (tile.children ? tile.children.forEach(walk) : leaves.push(tile.content.uri));
    walk(JSON.parse(readFileSync(join(dir, "tileset.json"), "utf8")).root);
    return leaves;
  }

  // The values of every point of a leaf tile of an export: its (x, y) in
  // the set's coordinates and each metadata property's value.
  async function leafPoints(dir, leaves) {
    const io = await gltfReader();
    const origin = JSON.parse(readFileSync(join(dir, "tileset.json"), "utf8")).root.transform.slice(12, 15);
    const found = [];
    for (const uri of leaves) {
      const doc = await readGlb(io, join(dir, uri));
      const prim = doc.getRoot().listMeshes()[0].listPrimitives()[0], m = doc.getRoot().listNodes()[0].getMatrix();
      const metadata = primitiveMetadata(doc, prim);
      const at = (i, p) => found.push({ xy: fromYUp(p).slice(0, 2).map((v, a) => v + origin[a]),
                                        values: Object.fromEntries(Object.entries(metadata).map(([k, f]) => [k, f(i)])) });
      const glb = readFileSync(join(dir, uri)), jsonLength = glb.readUInt32LE(12);
      const gltf = JSON.parse(glb.subarray(20, 20 + jsonLength).toString());
      const splats = gltf.meshes[0].primitives[0].extensions?.KHR_gaussian_splatting;
      if (!splats) {
        const position = prim.getAttribute("POSITION");
        for (let i = 0; i < position.getCount(); ++i) {
          const p = position.getElement(i, []);
          at(i, [0, 1, 2].map((r) => m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]));
        }
        continue;
      }
      // Splats' positions are in their SPZ, which glTF-Transform does not know: read by hand.
      const view = gltf.bufferViews[splats.extensions.KHR_gaussian_splatting_compression_spz_2.bufferView];
      const spz = readSpz(glb.subarray(28 + jsonLength + view.byteOffset, 28 + jsonLength + view.byteOffset + view.byteLength));
      for (let i = 0; i < spz.count; ++i) at(i, spz.get(i).position.map((v, a) => v + m[12 + a]));
    }
    return found;
  }

  for (const [name, { kept }] of Object.entries(sets))
    for (const dir of Object.keys(exports))
      test(`${name} set, ${dir}: the leaves' metadata holds every input point's values`, async () => {
        const info = JSON.parse(readFileSync(join(work, name, "tileset.json"), "utf8"));
        const attribute = (n) => info.attributes.find((a) => a.name === n);
        // Intensity as (value − min) / step (docs/FORMAT.md): exact where
        // value − min is a multiple of the set's step, within half of it
        // otherwise. The default set's step is more than 1 (the range
        // passes 12 bits), the minimum not 0: its codes are not its values.
        const intensity = attribute("intensity");
        assert.equal(intensity.offset, kIntensityMin);
        if (name === "quantized") assert.ok(intensity.scale > 1, `a step of ${intensity.scale}`);
        // GPS time in the set's step, less its minimum: within half a step,
        // plus the doubles' rounding at 4·10^8 s (two ulps: the metadata's
        // offset + scale · stored / (2^32 − 1) rounds by half an ulp in the
        // sum, far less in its other terms).
        const gps = attribute("gps_time");
        const gpsBound = gps && gps.scale / 2 + 2 * ulp(kGpsStart + count * kGpsStep);
        let exact = 0;
        const seen = new Set();
        // Each input point found once in the leaves, by its grid cell (its
        // position, within half the file's 0.01 step, finds it).
        for (const { xy, values } of await leafPoints(join(work, `${name}-${dir}`), leafTiles(join(work, `${name}-points`)))) {
          const [ix, iy] = xy.map((v) => Math.round(v / (kSpacing * kLasScale)));
          const p = input[iy * kSide + ix];
          assert.ok(p && !seen.has(p), `a point at cell ${ix}, ${iy}, once`);
          seen.add(p);
          const what = `the point at cell ${ix}, ${iy}`;
          assert.deepEqual(Object.keys(values).sort(), kept, `${what}: the attributes the set keeps`);
          if ((p.intensity - intensity.offset) % intensity.scale === 0) {
            assert.equal(values.intensity, p.intensity, `${what}'s intensity, kept exactly`);
            ++exact;
          } else {
            assert.ok(Math.abs(values.intensity - p.intensity) <= intensity.scale / 2, `${what}'s intensity ${values.intensity}, not ${p.intensity}`);
          }
          for (const k of ["classification", "user_data", "return_number", "number_of_returns"])
            if (kept.includes(k)) assert.equal(values[k], p[k], `${what}'s ${k}`);
          if (kept.includes("gps_time"))
            assert.ok(Math.abs(values.gps_time - p.gps_time) <= gpsBound, `${what}'s GPS time ${values.gps_time}, not ${p.gps_time}`);
        }
        assert.equal(seen.size, count, "every input point");
        if (name === "quantized") assert.ok(exact > 0 && exact < count, `${exact} intensities kept exactly, the others not`);
      });

  // 3D Tiles 1.1 tileset metadata: a property of the schema's class, and
  // its value, the input's.
  for (const [name, { constants }] of Object.entries(sets))
    for (const dir of Object.keys(exports))
      test(`${name} set, ${dir}: the set's constants are tileset metadata`, () => {
        const tileset = JSON.parse(readFileSync(join(work, `${name}-${dir}`, "tileset.json"), "utf8"));
        const cls = tileset.schema.classes[tileset.metadata.class];
        assert.deepEqual(Object.keys(tileset.metadata.properties).sort(), constants);
        for (const c of constants) {
          assert.deepEqual(cls.properties[c], { type: "SCALAR", componentType: "FLOAT64" }, c);
          assert.equal(tileset.metadata.properties[c], kOneValue[c], c);
        }
      });
});
