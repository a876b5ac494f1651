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
  nodes: number;
  surfels: number;
  colorBits: number;
  attributes: AttributeInfo[];
  weights: string;
  kernelScale: number;
  normalSource: string;
  hierarchyBytes: number;
  hierarchyPages: number;
  hierarchyCrc: number;
  blocksBytes: number;
  statistics: {
    elevationMin: number;
    elevationMax: number;
    intensity?: { min: number; max: number; p2: number; p98: number };
    classCounts: Map<number, number>;
  };
}

// The attributes whose place in a block the format fixes; every other listed
// attribute follows them in every block (FORMAT.md, "blocks.bin").
export const kFixedAttributes = ["position", "normal", "color", "weight", "radius", "edge_weight"];

// Largest tileset.json a reader accepts: the format's is a few kilobytes.
export const kMaxTilesetJsonBytes = 1 << 20;
export const kMaxBlockPoints = 4_194_304;
export const kMaxLevel = 20;
export const kMaxPositionBits = 30; // common/tileset_format.h

export class FormatError extends Error {}

function fail(what: string, why: string): never {
  throw new FormatError(`${what}: ${why}`);
}

function num(v: unknown, what: string, field: string): number {
  if (typeof v !== "number" || !Number.isFinite(v)) fail(what, `"${field}" is missing or not a number`);
  return v;
}
function vec3(v: unknown, what: string, field: string): Vec3 {
  if (!Array.isArray(v) || v.length !== 3) fail(what, `"${field}" is not an array of three numbers`);
  return [num(v[0], what, field), num(v[1], what, field), num(v[2], what, field)];
}
function obj(v: unknown, what: string, field: string): Record<string, unknown> {
  if (typeof v !== "object" || v === null || Array.isArray(v)) fail(what, `"${field}" is missing or not an object`);
  return v as Record<string, unknown>;
}

export function parseTileset(text: string, what: string): TilesetInfo {
  let j: Record<string, unknown>;
  try {
    j = obj(JSON.parse(text), what, "(top level)");
  } catch (e) {
    if (e instanceof FormatError) throw e;
    fail(what, `not JSON (${(e as Error).message})`);
  }
  if (j.format !== "surfcast-tileset") fail(what, `"format" is not "surfcast-tileset"`);
  const version = num(j.version, what, "version");
  if (version !== 1 && version !== 2) fail(what, `unsupported version ${version}`);
  const root = obj(j.root, what, "root");
  const bounds = obj(j.bounds, what, "bounds");
  const hierarchy = obj(j.hierarchy, what, "hierarchy");
  const blocks = obj(j.blocks, what, "blocks");
  if (blocks.codec !== "draco") fail(what, `blocks.codec is not "draco"`);
  if (!Array.isArray(j.attributes)) fail(what, `"attributes" is not an array`);
  const attributes = (j.attributes as unknown[]).map((a, i) => {
    const o = obj(a, what, `attributes[${i}]`);
    if (typeof o.name !== "string") fail(what, `attributes[${i}].name is not a string`);
    return {
      name: o.name,
      type: String(o.type ?? ""),
      components: num(o.components, what, `attributes[${i}].components`),
      quantizationBits: typeof o.quantization_bits === "number" ? o.quantization_bits : 0,
      kind: typeof o.kind === "string" ? o.kind : "",
      scale: typeof o.scale === "number" ? o.scale : 1,
      offset: typeof o.offset === "number" ? o.offset : 0,
    };
  });
  const stats = typeof j.statistics === "object" && j.statistics !== null ? (j.statistics as Record<string, any>) : {};
  // As in C++: statistics, where present, carry the elevation range.
  if (j.statistics !== undefined && (typeof stats.elevation?.min !== "number" || typeof stats.elevation?.max !== "number"))
    fail(what, "statistics.elevation.min and .max are not both numbers");
  const bmin = vec3(bounds.min, what, "bounds.min"), bmax = vec3(bounds.max, what, "bounds.max");
  const classCounts = new Map<number, number>();
  for (const [k, v] of Object.entries(stats.classification?.counts ?? {})) classCounts.set(Number(k), Number(v));
  const rootEdge = num(root.edge, what, "root.edge");
  if (!(rootEdge > 0)) fail(what, "root.edge is not positive");
  const colorBits = num(j.color_bits, what, "color_bits");
  if (colorBits !== 0 && colorBits !== 8 && colorBits !== 16) fail(what, `color_bits ${colorBits} is not 0, 8 or 16`);
  return {
    version,
    rootMin: vec3(root.min, what, "root.min"),
    rootEdge,
    boundsMin: bmin,
    boundsMax: bmax,
    levels: num(j.levels, what, "levels"),
    nodes: num(j.nodes, what, "nodes"),
    surfels: num(j.surfels, what, "surfels"),
    colorBits,
    attributes,
    weights: typeof j.weights === "string" ? j.weights : "none",
    kernelScale: typeof j.kernel_scale === "number" ? j.kernel_scale : 1,
    normalSource: typeof j.normal_source === "string" ? j.normal_source : "",
    hierarchyBytes: num(hierarchy.bytes, what, "hierarchy.bytes"),
    hierarchyPages: num(hierarchy.pages, what, "hierarchy.pages"),
    hierarchyCrc: num(hierarchy.crc32, what, "hierarchy.crc32"),
    blocksBytes: num(blocks.bytes, what, "blocks.bytes"),
    statistics: {
      // Without statistics (version 1), the bounds' z range, as in C++.
      elevationMin: j.statistics !== undefined ? stats.elevation.min : bmin[2],
      elevationMax: j.statistics !== undefined ? stats.elevation.max : bmax[2],
      intensity: stats.intensity,
      classCounts,
    },
  };
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
