// One node's block to GPU surfels: the CRC, the Draco header checked against
// the node record before Draco allocates anything (common/block_codec.cpp's
// readDracoHeader), decoding, and packing into the 32-byte GpuSurfel layout of
// client/shaders/shared_types.h (positions relative to the render origin,
// octahedral normal as two snorm16, RGBA8 colour, weight, edge weights).
// Runs in a Web Worker (decode_worker.ts); pure functions of its inputs.

import { crc32 } from "./crc32.js";
import { classColor, type ColorBy, intensityColor, returnColor, type RGB, viridis } from "./coloring.js";

// Where the decode worker loads draco3d's decoder from (the script and its
// WASM; absolute URLs): its first message, where the streamer says.
export interface DecoderUrls {
  draco: string;
  wasm: string;
}

export interface DecodeJob {
  id: number;
  key: string;
  blob: ArrayBuffer;
  crc: number;
  points: number;
  positionBits: number;
  min: [number, number, number]; // node minimum relative to the render origin
  edge: number;
  spacing: number;
  hasRadius: boolean;
  hasEdgeWeights: boolean;
  colorBits: number;
  weights: boolean;
  // blocks.codec "draco-columns": the positions in a kd-tree blob, the other
  // attributes in a sequential one; else "draco", one kd-tree blob of all.
  columns: boolean;
  extra: string[]; // the listed attributes after the fixed ones, in block order
  // Their widths (8, 16 or 32: tileset.json's types); draco-columns stores a
  // 32-bit one as two 16-bit columns, top first.
  extraBits: number[];
  coloring: ColoringSpec;
  // Picking: the attributes of the surfel at this index of the packed
  // surfels (the pick-th of those the class filter keeps), not the surfels.
  pick?: number;
}

// One surfel's attributes, as its block stores them.
export interface PickedSurfel {
  position: [number, number, number]; // relative to the render origin, in double
  normal: [number, number, number];
  radius: number; // r: the surfel's own or the node's spacing h
  color: [number, number, number] | null; // in [0, 1]; null where the set has no colour
  weight: number | null; // s_k; null without weights
  raw: Record<string, number>; // every attribute after the fixed ones, as stored (value = stored * scale + offset)
}

export interface ColoringSpec {
  by: ColorBy; // resolved: not "auto"
  originZ: number; // the render origin's z (elevation colours are world z)
  elevationMin: number;
  elevationMax: number;
  intensityScale: number;
  intensityOffset: number;
  intensityP2: number;
  intensityP98: number;
  hiddenClasses: number[];
}

export interface DecodeResult {
  id: number;
  surfels?: ArrayBuffer; // n * 32 bytes
  count?: number;
  picked?: PickedSurfel | null; // for a pick job: null where the index is past the packed surfels
  error?: string;
}

// What decoding may allocate (common/block_codec.h kMaxBlockDecodeBytes).
const kMaxDecodeBytes = 512 * 2 ** 20;
// The most attributes one of a block's point clouds may declare (kMaxBlockAttributes).
const kMaxAttributes = 128;
const kTypeBytes = [0, 1, 1, 2, 2, 4, 4, 8, 8, 4, 8, 1];

interface DracoHeader {
  points: number;
  attributes: number;
  components: number;
  valueBytes: number;
}

// common/block_codec.cpp's readDracoHeader: `kdTree`, the blob must be
// kd-tree coded, else sequentially; `what` names it in errors.
function readDracoHeader(b: Uint8Array, kdTree: boolean, what: string): DracoHeader | string {
  if (b.length < 17 || String.fromCharCode(...b.subarray(0, 5)) !== "DRACO") return `${what} is not Draco`;
  if (b[5] !== 2) return `${what} is bitstream version ${b[5]}.${b[6]}; readers take 2.x`;
  if (b[7] !== 0) return `${what} is not a point cloud`;
  if (b[8] !== (kdTree ? 1 : 0)) return kdTree ? `${what} is not kd-tree coded` : `${what} is not sequentially coded`;
  if ((b[9] | (b[10] << 8)) & 0x8000) return `${what} carries metadata`;
  const points = new DataView(b.buffer, b.byteOffset + 11, 4).getInt32(0, true);
  if (points < 0) return `${what} declares a negative point count`;
  if (b[15] !== 1) return `${what} has ${b[15]} attribute decoders, not 1`;
  let at = 16;
  const varint = (): number | null => {
    let v = 0;
    for (let shift = 0; shift < 35 && at < b.length; shift += 7) {
      const x = b[at++];
      v += (x & 0x7f) * 2 ** shift;
      if (!(x & 0x80)) return v <= 0xffffffff ? v : null;
    }
    return null;
  };
  const attributes = varint();
  if (attributes === null || attributes > kMaxAttributes) return `${what}'s attribute count is unreadable`;
  let components = 0, valueBytes = 0;
  for (let i = 0; i < attributes; ++i) {
    if (b.length - at < 4) return `${what} ends in its attribute descriptors`;
    const type = b[at + 1], comps = b[at + 2];
    at += 4;
    if (type < 1 || type > 11 || comps < 1 || comps > 4 || varint() === null)
      return `${what}'s attribute ${i} has ${comps} components of type ${type}`;
    components += comps;
    valueBytes += comps * kTypeBytes[type];
  }
  return { points, attributes, components, valueBytes };
}

// The LiDAR attributes and the opacity: their types are the format's own.
const kFixedTypeAttributes = ["intensity", "classification", "return_number", "number_of_returns", "opacity"];

// Whether extra[e] is two columns (common/block_codec.h's splitsColumn).
function splitsColumn(job: Pick<DecodeJob, "columns" | "extraBits">, e: number): boolean {
  return job.columns && job.extraBits[e] === 32;
}

// The block's blobs, their headers checked against the job before Draco
// allocates anything (common/block_codec.cpp's checkBlock), or the error.
export function checkBlock(b: Uint8Array, job: Pick<DecodeJob, "points" | "colorBits" | "weights" | "hasRadius" |
                           "hasEdgeWeights" | "columns" | "extra" | "extraBits">): { first: Uint8Array; columns: Uint8Array | null } | string {
  let others = 1 + (job.colorBits ? 1 : 0) + (job.weights ? 1 : 0) + (job.hasRadius ? 1 : 0) + (job.hasEdgeWeights ? 1 : 0);
  job.extra.forEach((_, e) => { others += splitsColumn(job, e) ? 2 : 1; });
  let first = b, columns: Uint8Array | null = null;
  if (job.columns) {
    if (b.length < 4) return "the block ends before its positions blob's length";
    const kdBytes = new DataView(b.buffer, b.byteOffset, 4).getUint32(0, true);
    if (kdBytes > b.length - 4) return `the block's positions blob of ${kdBytes} bytes runs past its end (${b.length} bytes)`;
    first = b.subarray(4, 4 + kdBytes);
    columns = b.subarray(4 + kdBytes);
  }
  const blobs: [Uint8Array, boolean, string, number][] = [[first, true, job.columns ? "the positions blob" : "the block", job.columns ? 1 : 1 + others]];
  if (columns) blobs.push([columns, false, "the columns blob", others]);
  let points = -1, components = 0, valueBytes = 0;
  for (const [blob, kdTree, what, attributes] of blobs) {
    const h = readDracoHeader(blob, kdTree, what);
    if (typeof h === "string") return h;
    if (h.points !== job.points) return `${what} declares ${h.points} points; the tile set declares ${job.points}`;
    if (h.attributes !== attributes) return `${what} has ${h.attributes} attributes; the tile set declares ${attributes}`;
    points = h.points;
    components += h.components;
    valueBytes += h.valueBytes;
  }
  if (points * (4 * components + valueBytes) > kMaxDecodeBytes)
    return `the block's ${points} points would take over ${kMaxDecodeBytes >> 20} MiB to decode`;
  return { first, columns };
}

function snorm16(v: number): number {
  v = Math.min(Math.max(Number.isFinite(v) ? v : 0, -1), 1);
  return Math.round(v * 32767) & 0xffff;
}

// Octahedral encoding (client/render/surfel_set.cpp packNormalOct).
export function packNormalOct(x: number, y: number, z: number): number {
  const l1 = Math.abs(x) + Math.abs(y) + Math.abs(z);
  if (!(l1 > 0) || !Number.isFinite(l1)) return 0;
  let u = x / l1, v = y / l1;
  if (z < 0) {
    const fu = (1 - Math.abs(v)) * (u < 0 ? -1 : 1), fv = (1 - Math.abs(u)) * (v < 0 ? -1 : 1);
    u = fu;
    v = fv;
  }
  return (snorm16(u) | (snorm16(v) << 16)) >>> 0;
}

// Largest edge-weight ratio a surfel carries (shared_types.h SC_EDGE_RATIO_MAX).
export const kEdgeRatioMax = 4;

// Edge weights as four unorm8 ratios / kEdgeRatioMax (surfel_set.cpp packEdgeWeights).
function packEdgeWeights(e: ArrayLike<number>, at: number): number {
  let packed = 0;
  for (let i = 0; i < 4; ++i) {
    const v = Number.isFinite(e[at + i]) ? e[at + i] / kEdgeRatioMax : 1 / kEdgeRatioMax;
    packed |= Math.round(Math.min(Math.max(v, 1 / 255), 1) * 255) << (8 * i);
  }
  return packed >>> 0;
}

const u8 = (v: number) => Math.round(Math.min(Math.max(Number.isFinite(v) ? v : 0, 0), 1) * 255);

// The subset of the draco3d module this file uses.
/* eslint-disable @typescript-eslint/no-explicit-any */
export type DracoModule = any;

export function decodeBlock(draco: DracoModule, job: DecodeJob): DecodeResult {
  const bytes = new Uint8Array(job.blob);
  const where = `node ${job.key}`;
  if (crc32(bytes) !== job.crc) return { id: job.id, error: `${where}: block CRC mismatch` };
  const blobs = checkBlock(bytes, job);
  if (typeof blobs === "string") return { id: job.id, error: `${where}: ${blobs}` };

  const decoder = new draco.Decoder();
  const cleanup: any[] = [decoder];
  // One of the block's point clouds, or an error.
  const decode = (blob: Uint8Array, what: string): any => {
    const buffer = new draco.DecoderBuffer();
    const pc = new draco.PointCloud();
    cleanup.push(pc, buffer);
    buffer.Init(new Int8Array(blob.buffer, blob.byteOffset, blob.length), blob.length);
    const status = decoder.DecodeBufferToPointCloud(buffer, pc);
    if (!status.ok()) throw new Error(`${where}: Draco decoding failed (${what}): ${status.error_msg()}`);
    if (pc.num_points() !== job.points) throw new Error(`${where}: the decoded block does not match its record`);
    return pc;
  };
  try {
    const first = decode(blobs.first, job.columns ? "positions" : "block");
    const rest = blobs.columns ? decode(blobs.columns, "columns") : first;
    const n = job.points;
    // Attribute `index` of `pc` as `type`; it must be stored as one of `stored`
    // (by default `type` itself), as common/block_codec.cpp's readAttribute
    // and readScalar demand.
    const dtOf = { u8: draco.DT_UINT8, u16: draco.DT_UINT16, u32: draco.DT_UINT32, f32: draco.DT_FLOAT32 };
    const read = (index: number, type: "u8" | "u16" | "u32" | "f32", components: number, pc: any = rest,
                  stored: number[] = [dtOf[type]]): ArrayLike<number> => {
      const a = decoder.GetAttribute(pc, index);
      if (a.num_components() !== components) throw new Error(`${where}: block attribute ${index} has ${a.num_components()} components, not ${components}`);
      if (!stored.includes(a.data_type())) throw new Error(`${where}: block attribute ${index} has an unexpected type`);
      const count = n * components;
      if (type === "f32") {
        const arr = new draco.DracoFloat32Array();
        try {
          if (!decoder.GetAttributeFloatForAllPoints(pc, a, arr)) throw new Error(`${where}: block attribute ${index} is not float`);
          const out = new Float32Array(count);
          for (let i = 0; i < count; ++i) out[i] = arr.GetValue(i);
          return out;
        } finally {
          draco.destroy(arr);
        }
      }
      const [dt, Ctor, bytesPer] = type === "u8" ? [draco.DT_UINT8, Uint8Array, 1] as const
        : type === "u16" ? [draco.DT_UINT16, Uint16Array, 2] as const : [draco.DT_UINT32, Uint32Array, 4] as const;
      const size = count * bytesPer;
      const ptr = draco._malloc(size);
      try {
        if (!decoder.GetAttributeDataArrayForAllPoints(pc, a, dt, size, ptr))
          throw new Error(`${where}: block attribute ${index} has an unexpected type`);
        return new Ctor(draco.HEAPU8.buffer.slice(ptr, ptr + size));
      } finally {
        draco._free(ptr);
      }
    };
    const positions = read(0, "u32", 3, first);
    let index = blobs.columns ? 0 : 1;
    const normals = read(index++, "f32", 3);
    const colors = job.colorBits ? read(index++, job.colorBits === 8 ? "u8" : "u16", 3) : null;
    const weights = job.weights ? read(index++, "f32", 1) : null;
    const radii = job.hasRadius ? read(index++, "f32", 1) : null;
    const edges = job.hasEdgeWeights ? read(index++, "f32", 4) : null;
    const lidar: Record<string, ArrayLike<number>> = {};
    job.extra.forEach((name, e) => {
      // Picking reads every attribute (unsigned, 8 to 32 bits: Draco widens them).
      const own = name === "intensity" ? "u16" : kFixedTypeAttributes.includes(name) ? "u8" : null;
      const type = job.pick !== undefined ? "u32" : own;
      // Stored as the format's own type, or a scalar as any unsigned integer of one component.
      const stored = own ? [dtOf[own]] : [draco.DT_UINT8, draco.DT_UINT16, draco.DT_UINT32];
      if (splitsColumn(job, e)) {
        // Two 16-bit columns, the top and the low bits; never the LiDAR attributes' or the opacity's.
        if (kFixedTypeAttributes.includes(name)) throw new Error(`${where}: block attribute ${index} has an unexpected type`);
        if (type) {
          const top = read(index, "u32", 1, rest, [draco.DT_UINT16]), low = read(index + 1, "u32", 1, rest, [draco.DT_UINT16]);
          const v = new Float64Array(n);
          for (let i = 0; i < n; ++i) v[i] = top[i] * 65536 + low[i];
          lidar[name] = v;
        }
        index += 2;
      } else {
        if (type) lidar[name] = read(index, type, 1, rest, stored);
        ++index;
      }
    });
    if (job.pick !== undefined) return { id: job.id, picked: picked(job, n, positions, normals, colors, weights, radii, lidar) };
    return pack(job, n, positions, normals, colors, weights, radii, edges, lidar);
  } catch (e) {
    return { id: job.id, error: (e as Error).message };
  } finally {
    for (const o of cleanup) draco.destroy(o);
  }
}

// Whether point i is left out by the colouring's class filter: pack() and
// picked() both skip these, so a packed index means the same point to both.
function hiddenBy(job: DecodeJob, lidar: Record<string, ArrayLike<number>>): (i: number) => boolean {
  const hidden = new Set(job.coloring.hiddenClasses), classes = lidar.classification;
  return hidden.size && classes ? (i) => hidden.has(classes[i]) : () => false;
}
// The node's quantization step: position = min + stored * step.
const positionStep = (job: DecodeJob) => job.edge / (2 ** job.positionBits - 1);

// The attributes of the job.pick-th surfel pack() keeps.
function picked(job: DecodeJob, n: number, positions: ArrayLike<number>, normals: ArrayLike<number>,
                colors: ArrayLike<number> | null, weights: ArrayLike<number> | null, radii: ArrayLike<number> | null,
                lidar: Record<string, ArrayLike<number>>): PickedSurfel | null {
  const hidden = hiddenBy(job, lidar);
  for (let i = 0, m = 0; i < n; ++i) {
    if (hidden(i)) continue;
    if (m++ !== job.pick) continue;
    const step = positionStep(job), colorScale = job.colorBits ? 1 / (2 ** job.colorBits - 1) : 0;
    const raw: Record<string, number> = {};
    for (const name of job.extra) raw[name] = lidar[name][i];
    return {
      position: [job.min[0] + positions[3 * i] * step, job.min[1] + positions[3 * i + 1] * step,
                 job.min[2] + positions[3 * i + 2] * step],
      normal: [normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]],
      radius: radii ? radii[i] : job.spacing,
      color: colors ? [colors[3 * i] * colorScale, colors[3 * i + 1] * colorScale, colors[3 * i + 2] * colorScale] : null,
      weight: weights ? weights[i] : null,
      raw,
    };
  }
  return null;
}

function pack(job: DecodeJob, n: number, positions: ArrayLike<number>, normals: ArrayLike<number>,
              colors: ArrayLike<number> | null, weights: ArrayLike<number> | null, radii: ArrayLike<number> | null,
              edges: ArrayLike<number> | null, lidar: Record<string, ArrayLike<number>>): DecodeResult {
  const out = new ArrayBuffer(n * 32);
  const f = new Float32Array(out), u = new Uint32Array(out);
  const step = positionStep(job);
  const colorScale = job.colorBits ? 1 / (2 ** job.colorBits - 1) : 0;
  const c = job.coloring;
  const hidden = hiddenBy(job, lidar);
  const classes = lidar.classification;
  const zRange = c.elevationMax - c.elevationMin;
  let m = 0;
  for (let i = 0; i < n; ++i) {
    if (hidden(i)) continue;
    const x = job.min[0] + positions[3 * i] * step, y = job.min[1] + positions[3 * i + 1] * step,
          z = job.min[2] + positions[3 * i + 2] * step;
    let rgb: RGB = [0.8, 0.8, 0.8];
    switch (c.by) {
      case "rgb":
        if (colors) rgb = [colors[3 * i] * colorScale, colors[3 * i + 1] * colorScale, colors[3 * i + 2] * colorScale];
        break;
      case "intensity":
        if (lidar.intensity) rgb = intensityColor(lidar.intensity[i] * c.intensityScale + c.intensityOffset, c.intensityP2, c.intensityP98);
        break;
      case "elevation":
        rgb = viridis(zRange > 0 ? (z + c.originZ - c.elevationMin) / zRange : 0.5);
        break;
      case "classification":
        if (classes) rgb = classColor(classes[i]);
        break;
      case "return":
        if (lidar.return_number && lidar.number_of_returns) rgb = returnColor(lidar.return_number[i], lidar.number_of_returns[i]);
        break;
    }
    const alpha = lidar.opacity ? lidar.opacity[i] : 255;
    const o = 8 * m;
    f[o] = x;
    f[o + 1] = y;
    f[o + 2] = z;
    f[o + 3] = radii ? radii[i] : job.spacing;
    u[o + 4] = packNormalOct(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
    u[o + 5] = (u8(rgb[0]) | (u8(rgb[1]) << 8) | (u8(rgb[2]) << 16) | (alpha << 24)) >>> 0;
    f[o + 6] = weights ? weights[i] : 1;
    u[o + 7] = edges ? packEdgeWeights(edges, 4 * i) : 0;
    ++m;
  }
  return { id: job.id, surfels: m === n ? out : out.slice(0, m * 32), count: m };
}
