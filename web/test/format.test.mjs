// The browser's format reader (web/src/format.ts) and block decoder
// (block_decode.ts, with draco3d's decoder) under node, on the format's
// conformance corpus (tests/conformance/), which tests/tileset_format_test.cpp
// and block_codec_test.cpp run through the C++ reader: both accept and reject
// the same cases.

import { createRequire } from "node:module";
import { test } from "node:test";
import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { conformance, loadModule } from "./load_module.mjs";

const format = await loadModule("src/format.ts");
const blocks = await loadModule("src/block_decode.ts");
const corpus = (name) => JSON.parse(readFileSync(join(conformance, name), "utf8"));

// A case's tileset.json text: `good` with the case's changes (the corpus's "about" says which).
function tilesetText(good, c) {
  if (c.text !== undefined) return c.text;
  const doc = structuredClone(good);
  const walk = (pointer) => {
    const path = pointer.split("/").slice(1).map((p) => p.replaceAll("~1", "/").replaceAll("~0", "~"));
    const key = path.pop();
    return [path.reduce((o, p) => o[p], doc), key];
  };
  for (const [pointer, value] of Object.entries(c.set ?? {})) {
    const [parent, key] = walk(pointer);
    parent[key] = value;
  }
  for (const pointer of c.remove ?? []) {
    const [parent, key] = walk(pointer);
    if (Array.isArray(parent)) parent.splice(Number(key), 1);
    else delete parent[key];
  }
  return JSON.stringify(doc, null, 2);
}

// What a good case's `read` names, from the reader's TilesetInfo.
const readers = {
  version: (i) => i.version,
  levels: (i) => i.levels,
  grid: (i) => i.grid,
  color_bits: (i) => i.colorBits,
  kernel_scale: (i) => i.kernelScale,
  weights: (i) => i.weights,
  blocks_bytes: (i) => i.blocksBytes,
  hierarchy_file: (i) => i.hierarchyFile,
  preview: (i) => [i.previewStride, i.previewDone],
  blocks_parts: (i) => i.blocksParts.map((p) => `${p.file}:${p.bytes}`),
  hierarchy_bytes: (i) => i.hierarchyBytes,
  hierarchy_pages: (i) => i.hierarchyPages,
  hierarchy_crc: (i) => i.hierarchyCrc,
  elevation: (i) => [i.statistics.elevationMin, i.statistics.elevationMax],
  attributes: (i) => i.attributes.map((a) => a.name),
};

test("tileset.json: the conformance cases (conformance/tileset_json.json)", async (t) => {
  const { good, cases } = corpus("tileset_json.json");
  for (const c of cases)
    await t.test(c.name, () => {
      const text = tilesetText(good, c);
      if (c.error !== undefined) {
        assert.throws(() => format.parseTileset(text, "tileset.json"), (e) => {
          assert.ok(e instanceof format.FormatError, String(e));
          assert.ok(e.message.startsWith("tileset.json: "), e.message);
          assert.ok(e.message.includes(c.error), `"${e.message}" does not name ${c.error}`);
          return true;
        });
        return;
      }
      const info = format.parseTileset(text, "tileset.json");
      for (const [field, want] of Object.entries(c.read)) {
        assert.ok(readers[field], `the corpus reads a field this test does not know: ${field}`);
        assert.deepEqual(readers[field](info), want, field);
      }
    });
});

// The hierarchy read as the streaming client reads it: the header and page
// table, then page 0 from the root, then each page its proxy record reaches.
function readAll(bytes, blocksBytes) {
  const index = format.readHierarchyIndex(bytes, bytes.length, "h.bin");
  const keys = [];
  const due = [[0, "0-0-0-0"]];
  for (let i = 0; i < due.length; ++i) {
    const [page, root] = due[i];
    const e = index.pages[page];
    const records = format.readHierarchyPage(index, page, bytes.subarray(e.offset, e.offset + e.records * format.kRecordBytes),
                                             root, blocksBytes, "h.bin");
    for (const r of records) {
      keys.push(r.key);
      if (r.flags & format.kFlagChildrenInPage) due.push([r.childPage, r.key]);
    }
  }
  return keys;
}

test("hierarchy.bin: the conformance cases (conformance/hierarchy.json)", async (t) => {
  const { blocks_bytes: blocksBytes, cases } = corpus("hierarchy.json");
  for (const c of cases)
    await t.test(c.name, () => {
      const bytes = new Uint8Array(Buffer.from(c.hierarchy, "hex"));
      if (c.error === undefined) return assert.deepEqual(readAll(bytes, blocksBytes), c.nodes);
      assert.throws(() => readAll(bytes, blocksBytes), (e) => {
        assert.ok(e instanceof format.FormatError, String(e));
        assert.ok(e.message.startsWith("h.bin: ") && e.message.includes(c.error), `"${e.message}" does not say ${c.error}`);
        return true;
      });
    });
});

test("blocks: the conformance cases (conformance/blocks.json)", async (t) => {
  const draco = await createRequire(import.meta.url)("draco3d").createDecoderModule({});
  const { expect: common, cases } = corpus("blocks.json");
  const coloring = { by: "rgb", originZ: 0, elevationMin: 0, elevationMax: 1, intensityScale: 1, intensityOffset: 0,
                     intensityP2: 0, intensityP98: 1, hiddenClasses: [] };
  for (const c of cases)
    await t.test(c.name, () => {
      const e = { ...common, ...c.expect };
      const bytes = Buffer.from(c.block, "hex");
      const result = blocks.decodeBlock(draco, {
        id: 1, key: "0-0-0-0", blob: bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.length), crc: c.crc,
        points: e.points, positionBits: 16, min: [0, 0, 0], edge: 1, spacing: 0.1, hasRadius: e.radii,
        hasEdgeWeights: e.edge_weights, colorBits: e.color_bits, weights: e.weights, columns: e.codec === "draco-columns",
        extra: e.extra ?? [], extraBits: e.extra_bits ?? [], coloring });
      if (c.error === undefined) {
        assert.equal(result.error, undefined);
        assert.equal(result.count, c.count);
      } else {
        assert.ok(result.error?.includes(c.error), `"${result.error}" does not say ${c.error}`);
      }
    });
});
