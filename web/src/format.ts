// The tile-set format as a reader needs it (docs/FORMAT.md; the C++ twin is
// common/tileset_format.cpp): tileset.json, hierarchy.bin's header, page
// table and pages, each checked as it arrives, and the node keys.

import { crc32 } from "./crc32.js";

export type Vec3 = [number, number, number];

export interface AttributeInfo {
  name: string;
  type: string;
  components: number;
  quantizationBits: number;
  kind: string;
  scale: number;
  offset: number;
}

export interface TilesetInfo {
  version: number;
  rootMin: Vec3;
  rootEdge: number;
  boundsMin: Vec3;
  boundsMax: Vec3;
  levels: number;
  grid: number;
  nodes: number;
  surfels: number;
  colorBits: number;
  attributes: AttributeInfo[];
  weights: string;
  kernelScale: number;
  normalSource: string;
  // "hierarchy.bin", or "hierarchy-XXXXXXXX.bin" in a set updated in place
  // (FORMAT.md, "Updates in place").
  hierarchyFile: string;
  hierarchyBytes: number;
  hierarchyPages: number;
  hierarchyCrc: number;
  blocksBytes: number;
  // How the blocks are coded (FORMAT.md, "blocks.bin").
  blockCodec: "draco" | "draco-columns";
  // The files the blocks lie in, in order: a node's block offset is into
  // their concatenation (FORMAT.md, "blocks.bin"); blocks.bin alone before version 3.
  blocksParts: { file: string; bytes: number }[];
  statistics: {
    elevationMin: number;
    elevationMax: number;
    intensity?: { min: number; max: number; p2: number; p98: number };
    classCounts: Map<number, number>;
  };
  // A preview (surfcast-build --preview): built from every previewStride-th
  // input point while the set itself is built; 0: a set.
  previewStride: number;
  // A refinement of the preview (a build in progress): the share of the
  // input points at full detail, in [0, 1); 0 in the first preview.
  previewDone: number;
}

// The attributes whose place in a block the format fixes; every other listed
// attribute follows them in every block (FORMAT.md, "blocks.bin").
export const kFixedAttributes = ["position", "normal", "color", "weight", "radius", "edge_weight"];

// How a block of the set is laid out past its fixed attributes (the fields
// of block_decode.ts's DecodeJob): the codec, and the listed attributes after
// the fixed ones, in block order, with their widths in bits.
export function blockLayout(info: TilesetInfo): { columns: boolean; extra: string[]; extraBits: number[] } {
  const extra = info.attributes.filter((a) => !kFixedAttributes.includes(a.name));
  return { columns: info.blockCodec === "draco-columns", extra: extra.map((a) => a.name),
           extraBits: extra.map((a) => (a.type === "uint32" ? 32 : a.type === "uint16" ? 16 : 8)) }; // common/block_codec.h scalarBits
}

// Largest tileset.json a reader accepts (common/tile_source.h's
// kMaxTilesetJsonBytes): the format's is a few kilobytes.
export const kMaxTilesetJsonBytes = 16 << 20;
export const kMaxBlockPoints = 4_194_304;
export const kMaxLevel = 20;
export const kMaxPositionBits = 30; // common/tileset_format.h
const kOldestFormatVersion = 1, kFormatVersion = 3;
const kMaxBlocksParts = 65536; // common/tileset_format.h

export class FormatError extends Error {}

function fail(what: string, why: string): never {
  throw new FormatError(`${what}: ${why}`);
}

// tileset.json's fields, each read with its path ("hierarchy.bytes",
// "attributes[2].scale") in the error, as common/tileset_format.cpp does: both
// run tests/conformance/tileset_json.json. Integers are whole numbers within
// the field's range (2.0 is 2, as in C++), u64 fields up to 2^53, what a
// double holds exactly (C++ takes them to 2^64: 8 PB of blocks and beyond).
type Json = Record<string, unknown>;
const joined = (parent: string, key: string) => (parent ? `${parent}.${key}` : key);
// A value quoted in an error: at most about 60 characters of it, cut between characters.
function shown(v: unknown): string {
  const s = JSON.stringify(v) ?? String(v);
  if (s.length <= 64) return s;
  const high = s.charCodeAt(59) >= 0xd800 && s.charCodeAt(59) < 0xdc00;  // a surrogate pair's first half
  return `${s.slice(0, high ? 59 : 60)}...`;
}
function member(o: Json, parent: string, key: string): unknown {
  if (!Object.hasOwn(o, key)) throw new FormatError(`${joined(parent, key)}: missing`);
  return o[key];
}
function isObject(v: unknown): v is Json {
  return typeof v === "object" && v !== null && !Array.isArray(v);
}
function object(o: Json, parent: string, key: string): Json {
  const v = member(o, parent, key);
  if (!isObject(v)) throw new FormatError(`${joined(parent, key)}: not an object`);
  return v;
}
function integer(o: Json, parent: string, key: string, min: number, max: number): number {
  const v = member(o, parent, key);
  if (typeof v !== "number" || !Number.isInteger(v) || v < min || v > max)
    throw new FormatError(`${joined(parent, key)}: ${shown(v)} is not an integer in its range`);
  return v;
}
const kU32 = 0xffffffff, kI32 = 0x7fffffff, kU64 = Number.MAX_SAFE_INTEGER;
function finite(v: unknown, path: string): number {
  if (typeof v !== "number" || !Number.isFinite(v)) throw new FormatError(`${path}: ${shown(v)} is not a finite number`);
  return v;
}
const number = (o: Json, parent: string, key: string) => finite(member(o, parent, key), joined(parent, key));
function text(o: Json, parent: string, key: string): string {
  const v = member(o, parent, key);
  if (typeof v !== "string") throw new FormatError(`${joined(parent, key)}: ${shown(v)} is not a string`);
  return v;
}
function vec3(o: Json, parent: string, key: string): Vec3 {
  const v = member(o, parent, key), path = joined(parent, key);
  if (!Array.isArray(v) || v.length !== 3) throw new FormatError(`${path}: not an array of three numbers`);
  return [finite(v[0], path), finite(v[1], path), finite(v[2], path)];
}

export function parseTileset(json: string, what: string): TilesetInfo {
  let j: unknown;
  try {
    j = JSON.parse(json);
  } catch (e) {
    fail(what, `not valid JSON (${(e as Error).message})`);
  }
  if (!isObject(j)) fail(what, "not a JSON object");
  try {
    return readFields(j);
  } catch (e) {
    if (e instanceof FormatError) fail(what, e.message);
    throw e;
  }
}

function readFields(j: Json): TilesetInfo {
  if (text(j, "", "format") !== "surfcast-tileset") throw new FormatError(`format: not "surfcast-tileset"`);
  const version = integer(j, "", "version", -kI32 - 1, kI32);
  if (version < kOldestFormatVersion || version > kFormatVersion)
    throw new FormatError(`version: unsupported version ${version} (this reader takes ${kOldestFormatVersion} to ${kFormatVersion})`);
  text(j, "", "generator");
  integer(j, "", "input_points", 0, kU64);
  const surfels = integer(j, "", "surfels", 0, kU64);
  const nodes = integer(j, "", "nodes", 0, kU64);
  const levels = integer(j, "", "levels", -kI32 - 1, kI32);
  if (levels < 1 || levels > kMaxLevel + 1) throw new FormatError(`levels: ${levels} is not 1 to ${kMaxLevel + 1}`);
  const grid = integer(j, "", "grid", -kI32 - 1, kI32);
  if (grid < 1) throw new FormatError(`grid: ${grid} is not positive`);
  const root = object(j, "", "root");
  const rootMin = vec3(root, "root", "min");
  const rootEdge = number(root, "root", "edge");
  if (!(rootEdge > 0)) throw new FormatError("root.edge: not positive");
  const bounds = object(j, "", "bounds");
  const boundsMin = vec3(bounds, "bounds", "min"), boundsMax = vec3(bounds, "bounds", "max");
  const colorBits = integer(j, "", "color_bits", -kI32 - 1, kI32);
  if (colorBits !== 0 && colorBits !== 8 && colorBits !== 16)
    throw new FormatError(`color_bits: ${colorBits}, not 0, 8 or 16`);
  const list = member(j, "", "attributes");
  if (!Array.isArray(list)) throw new FormatError("attributes: not an array");
  const attributes = list.map((a: unknown, i): AttributeInfo => {
    const at = `attributes[${i}]`;
    if (!isObject(a)) throw new FormatError(`${at}: not an object`);
    const o = a;
    const added = {
      name: text(o, at, "name"),
      type: text(o, at, "type"),
      components: integer(o, at, "components", -kI32 - 1, kI32),
      quantizationBits: integer(o, at, "quantization_bits", -kI32 - 1, kI32),
      kind: Object.hasOwn(o, "kind") ? text(o, at, "kind") : "",
      scale: Object.hasOwn(o, "scale") ? number(o, at, "scale") : 1,
      offset: Object.hasOwn(o, "offset") ? number(o, at, "offset") : 0,
    };
    const of = ` (attribute ${added.name})`;
    if (added.scale === 0) throw new FormatError(`${at}.scale: 0${of}`);
    if (added.components < 1 || added.components > 4)
      throw new FormatError(`${at}.components: ${added.components} is not 1 to 4${of}`);
    // Draco quantizes with 1 to 30 bits; 0 means not quantized.
    if (added.quantizationBits < 0 || added.quantizationBits > 30)
      throw new FormatError(`${at}.quantization_bits: ${added.quantizationBits} is not 0 to 30${of}`);
    return added;
  });
  // Absent in version 1: the elevation range is the bounds'.
  const statistics: TilesetInfo["statistics"] = { elevationMin: boundsMin[2], elevationMax: boundsMax[2], classCounts: new Map() };
  if (Object.hasOwn(j, "statistics")) {
    const js = object(j, "", "statistics");
    const elevation = object(js, "statistics", "elevation");
    statistics.elevationMin = number(elevation, "statistics.elevation", "min");
    statistics.elevationMax = number(elevation, "statistics.elevation", "max");
    if (Object.hasOwn(js, "intensity")) {
      const ji = object(js, "statistics", "intensity");
      const at = "statistics.intensity";
      statistics.intensity = { min: number(ji, at, "min"), max: number(ji, at, "max"), p2: number(ji, at, "p2"),
                               p98: number(ji, at, "p98") };
    }
    if (Object.hasOwn(js, "classification")) {
      const at = "statistics.classification.counts";
      const counts = object(object(js, "statistics", "classification"), "statistics.classification", "counts");
      for (const key of Object.keys(counts)) {
        // A class as C++ writes it: digits without leading zeros.
        if (!/^(0|[1-9]\d{0,2})$/.test(key) || Number(key) > 255) throw new FormatError(`${at}: '${key}' is not a class (0-255)`);
        statistics.classCounts.set(Number(key), integer(counts, at, key, 0, kU64));
      }
    }
  }
  const normalSource = text(j, "", "normal_source");
  const weights = text(j, "", "weights");
  // Absent in sets written before it existed, whose weights assumed k = 1.
  const kernelScale = Object.hasOwn(j, "kernel_scale") ? number(j, "", "kernel_scale") : 1;
  if (!(kernelScale > 0)) throw new FormatError("kernel_scale: not positive");
  if (Object.hasOwn(j, "texture_filter")) text(j, "", "texture_filter");
  const hierarchy = object(j, "", "hierarchy");
  const hierarchyFile = Object.hasOwn(hierarchy, "file") ? text(hierarchy, "hierarchy", "file") : "hierarchy.bin";
  if (!/^hierarchy(-[0-9a-f]{8})?\.bin$/.test(hierarchyFile))
    throw new FormatError(`hierarchy.file: '${hierarchyFile}' is not hierarchy.bin or hierarchy-XXXXXXXX.bin`);
  const hierarchyBytes = integer(hierarchy, "hierarchy", "bytes", 0, kU64);
  const hierarchyPages = integer(hierarchy, "hierarchy", "pages", 0, kU32);
  integer(hierarchy, "hierarchy", "page_depth", 0, kU32);
  const hierarchyCrc = integer(hierarchy, "hierarchy", "crc32", 0, kU32);
  const blocks = object(j, "", "blocks");
  const blocksBytes = integer(blocks, "blocks", "bytes", 0, kU64);
  const blockCodec = text(blocks, "blocks", "codec");
  if (blockCodec !== "draco" && blockCodec !== "draco-columns")
    throw new FormatError(`blocks.codec: '${blockCodec}' is not "draco" or "draco-columns"`);
  if (Object.hasOwn(blocks, "parts") !== (version >= 3))
    throw new FormatError(version >= 3 ? "blocks.parts: missing (version 3 lists the blocks' files)" : "blocks.parts: only in version 3");
  let blocksParts = [{ file: "blocks.bin", bytes: blocksBytes }];
  if (version >= 3) {
    const parts = blocks.parts;
    if (!Array.isArray(parts)) throw new FormatError("blocks.parts: not an array");
    if (parts.length === 0 || parts.length > kMaxBlocksParts)
      throw new FormatError(`blocks.parts: ${parts.length} files, not 1 to ${kMaxBlocksParts}`);
    blocksParts = [];
    const files = new Set<string>();
    let sum = 0;
    parts.forEach((p: unknown, i: number) => {
      const at = `blocks.parts[${i}]`;
      if (!isObject(p)) throw new FormatError(`${at}: not an object`);
      const part = p as Json;
      const file = text(part, at, "file");
      const bytes = integer(part, at, "bytes", 0, kU64);
      if (!/^blocks(-[0-9a-f]{8})?\.bin$/.test(file)) throw new FormatError(`${at}.file: '${file}' is not blocks.bin or blocks-XXXXXXXX.bin`);
      if (files.has(file)) throw new FormatError(`${at}.file: '${file}' listed twice`);
      files.add(file);
      if (bytes === 0) throw new FormatError(`${at}.bytes: 0, or past 2^64 in all`);
      sum += bytes;
      blocksParts.push({ file, bytes });
    });
    if (sum !== blocksBytes) throw new FormatError(`blocks.parts: the files' bytes add up to ${sum}, not blocks.bytes ${blocksBytes}`);
  }
  let previewStride = 0, previewDone = 0;
  if ("preview" in j) {
    const preview = object(j, "", "preview");
    previewStride = integer(preview, "preview", "stride", 1, 2 ** 32 - 1);
    if ("done" in preview) {
      previewDone = number(preview, "preview", "done");
      if (!(previewDone >= 0 && previewDone < 1)) throw new FormatError(`preview.done: ${previewDone} is not in [0, 1)`);
    }
  }
  return { version, rootMin, rootEdge, boundsMin, boundsMax, levels, grid, nodes, surfels, colorBits, attributes, weights,
           kernelScale, normalSource, hierarchyFile, hierarchyBytes, hierarchyPages, hierarchyCrc, blocksBytes, blockCodec, blocksParts, statistics,
           previewStride, previewDone };
}

// The file holding a node's block and the offset there (common/tileset_format.h's placeBlock).
export function placeBlock(parts: { file: string; bytes: number }[], offset: number, size: number): { file: string; offset: number } {
  let start = 0;
  for (const p of parts) {
    if (offset < start + p.bytes) {
      if (size > start + p.bytes - offset) throw new FormatError(`${size} bytes at ${offset} cross the end of ${p.file}`);
      return { file: p.file, offset: offset - start };
    }
    start += p.bytes;
  }
  throw new FormatError(`${size} bytes at ${offset} lie past the blocks' ${start} bytes`);
}

export function attribute(info: TilesetInfo, name: string): AttributeInfo | undefined {
  return info.attributes.find((a) => a.name === name);
}

// Node flags (FORMAT.md, node record).
export const kFlagConeFull = 1;
export const kFlagHasRadius = 2;
export const kFlagChildrenInPage = 4;
export const kFlagInputPoints = 8;
export const kFlagEdgeWeights = 16;

export interface NodeRecord {
  key: string; // "L-X-Y-Z"
  level: number;
  x: number;
  y: number;
  z: number;
  childMask: number;
  flags: number;
  blockOffset: number;
  blockSize: number;
  blockCrc: number;
  surfelCount: number;
  spacing: number;
  coneAxis: Vec3;
  coneCos: number;
  positionBits: number;
  childPage: number;
}

export const keyOf = (level: number, x: number, y: number, z: number) => `${level}-${x}-${y}-${z}`;
export function childKey(n: { level: number; x: number; y: number; z: number }, c: number): string {
  return keyOf(n.level + 1, 2 * n.x + ((c >> 2) & 1), 2 * n.y + ((c >> 1) & 1), 2 * n.z + (c & 1));
}
export function parentKey(n: NodeRecord): string {
  return keyOf(n.level - 1, n.x >>> 1, n.y >>> 1, n.z >>> 1);
}
export function childIndex(n: NodeRecord): number {
  return ((n.x & 1) << 2) | ((n.y & 1) << 1) | (n.z & 1);
}

export const kHeaderBytes = 32;
export const kRecordBytes = 64;
const kPageEntryBytes = 16;

function decodeRecord(v: DataView, at: number): NodeRecord {
  const level = v.getUint8(at), x = v.getUint32(at + 4, true), y = v.getUint32(at + 8, true), z = v.getUint32(at + 12, true);
  return {
    key: keyOf(level, x, y, z),
    level,
    x,
    y,
    z,
    childMask: v.getUint8(at + 1),
    flags: v.getUint16(at + 2, true),
    blockOffset: Number(v.getBigUint64(at + 16, true)),
    blockSize: v.getUint32(at + 24, true),
    blockCrc: v.getUint32(at + 28, true),
    surfelCount: v.getUint32(at + 32, true),
    spacing: v.getFloat32(at + 36, true),
    coneAxis: [v.getFloat32(at + 40, true), v.getFloat32(at + 44, true), v.getFloat32(at + 48, true)],
    coneCos: v.getFloat32(at + 52, true),
    positionBits: v.getUint8(at + 56),
    childPage: v.getUint32(at + 60, true),
  };
}

export interface PageEntry {
  offset: number;
  records: number;
  crc: number;
}
export interface HierarchyIndex {
  pageDepth: number;
  nodeCount: number;
  pages: PageEntry[];
}

// Bytes of the header and page table, from the header's page count.
export function indexBytes(header: Uint8Array): number {
  return kHeaderBytes + kPageEntryBytes * new DataView(header.buffer, header.byteOffset, header.byteLength).getUint32(12, true);
}

export function readHierarchyIndex(bytes: Uint8Array, fileBytes: number, what: string): HierarchyIndex {
  if (bytes.length < kHeaderBytes || fileBytes < kHeaderBytes) fail(what, "shorter than the 32-byte header");
  const v = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (String.fromCharCode(bytes[0], bytes[1], bytes[2], bytes[3]) !== "SCHY") fail(what, "bad magic at byte 0 (expected SCHY)");
  const version = v.getUint32(4, true);
  if (version < 1 || version > 2) fail(what, `unsupported version ${version} at byte 4`);
  if (v.getUint32(8, true) !== kRecordBytes) fail(what, "record size at byte 8 is not 64");
  const pageCount = v.getUint32(12, true);
  const tableEnd = kHeaderBytes + pageCount * kPageEntryBytes;
  if (tableEnd > fileBytes || tableEnd > bytes.length) fail(what, "page table runs past the end of the file");
  if (crc32(bytes.subarray(kHeaderBytes, tableEnd)) !== v.getUint32(24, true)) fail(what, "page table CRC mismatch");
  const pages: PageEntry[] = [];
  for (let p = 0; p < pageCount; ++p) {
    const at = kHeaderBytes + p * kPageEntryBytes;
    const e = { offset: Number(v.getBigUint64(at, true)), records: v.getUint32(at + 8, true), crc: v.getUint32(at + 12, true) };
    if (e.records === 0 || e.offset < tableEnd || e.offset > fileBytes || e.records * kRecordBytes > fileBytes - e.offset)
      fail(what, `page ${p} at byte ${e.offset}: out of the file's bounds`);
    pages.push(e);
  }
  return { pageDepth: v.getUint32(16, true), nodeCount: v.getUint32(20, true), pages };
}

// The records of page `page`, checked: its CRC, its first record equal to
// `root` (the record pointing to it; the root node for page 0), breadth-first
// order, blocks inside blocks.bin. The first record of a later page is its
// proxy, which the caller has already: it is left out.
export function readHierarchyPage(index: HierarchyIndex, page: number, bytes: Uint8Array, root: string,
                                  blocksBytes: number, what: string): NodeRecord[] {
  const entry = index.pages[page];
  if (!entry) fail(what, `no page ${page}`);
  const where = `${what}: page ${page} at byte ${entry.offset}`;
  if (bytes.length !== entry.records * kRecordBytes)
    fail(where, `${bytes.length} bytes, not the ${entry.records} records of the page table`);
  if (crc32(bytes) !== entry.crc) fail(where, "CRC mismatch");
  const v = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const recs: NodeRecord[] = [];
  for (let i = 0; i < entry.records; ++i) recs.push(decodeRecord(v, i * kRecordBytes));
  if (recs[0].key !== root) fail(where, "page root does not match the record that points to it");
  let next = 1;
  for (const r of recs) {
    const node = `node ${r.key}`;
    if (r.level > kMaxLevel) fail(where, `${node}: level beyond ${kMaxLevel}`);
    if (r.blockOffset > blocksBytes || r.blockSize > blocksBytes - r.blockOffset)
      fail(where, `${node} points past the end of blocks.bin`);
    // Positions are min + q * edge / (2^b - 1): b = 0 divides by zero; h sizes every splat.
    if (r.positionBits < 1 || r.positionBits > kMaxPositionBits)
      fail(where, `${node}: ${r.positionBits} position bits, not 1 to ${kMaxPositionBits}`);
    if (!(Number.isFinite(r.spacing) && r.spacing > 0)) fail(where, `${node}: spacing ${r.spacing} is not a positive number`);
    if (r.surfelCount > kMaxBlockPoints) fail(where, `${node} declares ${r.surfelCount} surfels, more than ${kMaxBlockPoints}`);
    if (r.flags & kFlagChildrenInPage) {
      if (r.childPage <= page || r.childPage >= index.pages.length || r.childMask === 0)
        fail(where, `${node}: bad child page ${r.childPage}`);
      continue;
    }
    for (let c = 0; c < 8; ++c) {
      if (!(r.childMask & (1 << c))) continue;
      if (next >= recs.length || recs[next].key !== childKey(r, c)) fail(where, `children of ${node} out of order`);
      ++next;
    }
  }
  if (next !== recs.length) fail(where, "records not reachable from the page root");
  return page > 0 ? recs.slice(1) : recs;
}

export function nodeEdge(info: TilesetInfo, level: number): number {
  return info.rootEdge / 2 ** level;
}
export function nodeMin(info: TilesetInfo, n: NodeRecord): Vec3 {
  const e = nodeEdge(info, n.level);
  return [info.rootMin[0] + n.x * e, info.rootMin[1] + n.y * e, info.rootMin[2] + n.z * e];
}
