// Which nodes to draw for a view: the same rules as client/stream/lod_selection
// (Ren et al. 2002, §6.2), ported line for line so that the browser and the
// Vulkan client converge to the same nodes. Frustum culling of node boxes
// grown by the splat extent, backface culling by the visibility cones, level
// choice by warping the box to the screen (h times the largest pixels per unit
// over its corners), replacement refinement coarsest gap first (weighted
// towards the view centre) under a splat and a memory budget. The tree may be
// known in part: a node whose children are in a page not yet added is drawn
// meanwhile and its page reported missing.

import { type Camera, cameraAxes, dot, length, normalize, sub, viewportScale } from "./camera.js";
import { childIndex, kFlagChildrenInPage, kFlagConeFull, type NodeRecord, nodeEdge, nodeMin, parentKey,
         type TilesetInfo, type Vec3 } from "./format.js";

// Splat extent beyond the surfel centres a node box grows by before culling.
const kExtentFactor = 2.0;

export interface LodParams {
  targetPixels: number;
  frustumCulling: boolean;
  backfaceCulling: boolean;
  // Nodes whose box misses the clip box (world coordinates) are culled: none
  // of their surfels would be drawn (RenderSettings.clip).
  clip?: Box;
  splatBudget: number;
  memoryBudget: number; // bytes of the nodes a view uses, 32 per surfel in whole granules
}

// Surfels per granule of GPU memory: a row of a node's texture (renderer.ts),
// as a page of the Vulkan client's pool (SurfelPool::kPageSurfels), so that
// both clients count a node alike under a memory budget.
export const kGranuleSurfels = 1024;
// Bytes a node occupies when resident: its surfels, 32 bytes each, in whole granules.
export const residentBytes = (surfels: number) => Math.ceil(surfels / kGranuleSurfels) * kGranuleSurfels * 32;

export interface LodStats {
  visited: number;
  frustumCulled: number;
  clipCulled: number;
  backfaceCulled: number;
  waiting: number;
  budgetLimited: number;
  splats: number;
  missing: [number, number][]; // (node index, priority)
  missingPages: [number, number][]; // (node whose children the page holds, priority)
  used: number[];
}

export interface Box {
  min: Vec3;
  max: Vec3;
}

interface Frame {
  eye: Vec3;
  right: Vec3;
  up: Vec3;
  forward: Vec3;
  eta: number;
  halfW: number;
  halfH: number;
}

// Closed boxes sharing at least a point.
export function intersects(a: Box, b: Box): boolean {
  return a.min[0] <= b.max[0] && b.min[0] <= a.max[0] && a.min[1] <= b.max[1] && b.min[1] <= a.max[1] &&
         a.min[2] <= b.max[2] && b.min[2] <= a.max[2];
}

function corner(b: Box, i: number): Vec3 {
  return [i & 1 ? b.max[0] : b.min[0], i & 2 ? b.max[1] : b.min[1], i & 4 ? b.max[2] : b.min[2]];
}

function toCamera(f: Frame, p: Vec3): Vec3 {
  const d = sub(p, f.eye);
  return [dot(d, f.right), dot(d, f.up), dot(d, f.forward)];
}

function outsideFrustum(f: Frame, b: Box): boolean {
  const c = [0, 1, 2, 3, 4, 5, 6, 7].map((i) => toCamera(f, corner(b, i)));
  const all = (outside: (p: Vec3) => boolean) => c.every(outside);
  return all((p) => p[2] <= 0) || all((p) => f.eta * p[0] > f.halfW * p[2]) || all((p) => -f.eta * p[0] > f.halfW * p[2]) ||
         all((p) => f.eta * p[1] > f.halfH * p[2]) || all((p) => -f.eta * p[1] > f.halfH * p[2]);
}

function backfacing(n: NodeRecord, b: Box, eye: Vec3): boolean {
  if (n.flags & kFlagConeFull || !(n.coneCos > -1)) return false;
  const centre: Vec3 = [0.5 * (b.min[0] + b.max[0]), 0.5 * (b.min[1] + b.max[1]), 0.5 * (b.min[2] + b.max[2])];
  const radius = 0.5 * length(sub(b.max, b.min));
  const toEye = sub(eye, centre);
  const distance = length(toEye);
  if (distance <= radius) return false;
  const beta = Math.asin(radius / distance);
  const alpha = Math.acos(Math.max(-1, Math.min(1, n.coneCos)));
  const gamma = Math.acos(Math.max(-1, Math.min(1, dot(normalize(n.coneAxis), [toEye[0] / distance, toEye[1] / distance, toEye[2] / distance]))));
  return gamma > 0.5 * Math.PI + alpha + beta;
}

// The order nodes are refined in: larger priority first, and of equal
// priorities the smaller key (level, x, y, z), as the C++ client orders them
// (client/stream/lod_selection.cpp), so that both choose the same nodes
// under a budget.
interface Ranked { priority: number; level: number; x: number; y: number; z: number }
function before(a: Ranked, b: Ranked): boolean {
  if (a.priority !== b.priority) return a.priority > b.priority;
  if (a.level !== b.level) return a.level < b.level;
  if (a.x !== b.x) return a.x < b.x;
  if (a.y !== b.y) return a.y < b.y;
  return a.z < b.z;
}

// A max-heap of drawn nodes in that order.
class Heap<T extends Ranked> {
  private a: T[] = [];
  get size() { return this.a.length; }
  push(v: T) {
    const a = this.a;
    a.push(v);
    for (let i = a.length - 1; i > 0;) {
      const p = (i - 1) >> 1;
      if (!before(a[i], a[p])) break;
      [a[p], a[i]] = [a[i], a[p]];
      i = p;
    }
  }
  pop(): T {
    const a = this.a, top = a[0], last = a.pop()!;
    if (a.length) {
      a[0] = last;
      for (let i = 0; ;) {
        const l = 2 * i + 1, r = l + 1;
        let m = i;
        if (l < a.length && before(a[l], a[m])) m = l;
        if (r < a.length && before(a[r], a[m])) m = r;
        if (m === i) break;
        [a[m], a[i]] = [a[i], a[m]];
        i = m;
      }
    }
    return top;
  }
}

export interface SelectedNode {
  index: number;
  projectedSpacing: number;
}

export class LodSelector {
  readonly nodes: NodeRecord[] = [];
  private children: Int32Array[] = [];
  private index = new Map<string, number>();
  private root = -1;

  constructor(private info: TilesetInfo, nodes: NodeRecord[]) {
    this.addNodes(nodes);
  }

  // The index of the node with this key, if it is known.
  find(key: string): number | undefined {
    return this.index.get(key);
  }

  // A further page's records (without its proxy): they take the next indices.
  addNodes(nodes: NodeRecord[]) {
    const first = this.nodes.length;
    for (const n of nodes) {
      this.index.set(n.key, this.nodes.length);
      if (n.level === 0) this.root = this.nodes.length;
      this.nodes.push(n);
      this.children.push(new Int32Array(8).fill(-1));
    }
    for (let i = first; i < this.nodes.length; ++i) {
      const n = this.nodes[i];
      if (n.level === 0) continue;
      const parent = this.index.get(parentKey(n));
      if (parent !== undefined) this.children[parent][childIndex(n)] = i;
    }
  }

  box(i: number): Box {
    const lo = nodeMin(this.info, this.nodes[i]);
    const e = nodeEdge(this.info, this.nodes[i].level);
    return { min: lo, max: [lo[0] + e, lo[1] + e, lo[2] + e] };
  }

  select(camera: Camera, width: number, height: number, params: LodParams, resident: (i: number) => boolean,
         st: LodStats): SelectedNode[] {
    Object.assign(st, { visited: 0, frustumCulled: 0, clipCulled: 0, backfaceCulled: 0, waiting: 0, budgetLimited: 0, splats: 0,
                        missing: [], missingPages: [], used: [] });
    const out: SelectedNode[] = [];
    if (this.root < 0 || width <= 0 || height <= 0) return out;
    const a = cameraAxes(camera);
    const f: Frame = { eye: camera.eye, right: a.right, up: a.up, forward: a.forward, eta: viewportScale(camera, height),
                       halfW: 0.5 * width, halfH: 0.5 * height };
    const nearDistance = 1e-9 * Math.max(1, this.info.rootEdge);
    const nodes = this.nodes;

    const culled = (i: number): Box | null => {
      const b = this.box(i);
      if (params.clip && !intersects(b, params.clip)) {
        ++st.clipCulled;
        return null;
      }
      const x = kExtentFactor * nodes[i].spacing;
      const grown: Box = { min: [b.min[0] - x, b.min[1] - x, b.min[2] - x], max: [b.max[0] + x, b.max[1] + x, b.max[2] + x] };
      if (params.frustumCulling && outsideFrustum(f, grown)) {
        ++st.frustumCulled;
        return null;
      }
      if (params.backfaceCulling && backfacing(nodes[i], grown, f.eye)) {
        ++st.backfaceCulled;
        return null;
      }
      return grown;
    };
    const projectedSpacing = (i: number, b: Box) => {
      let nearest = Infinity;
      for (let c = 0; c < 8; ++c) nearest = Math.min(nearest, toCamera(f, corner(b, c))[2]);
      if (!(nearest > nearDistance)) return Infinity;
      return (nodes[i].spacing * f.eta) / nearest;
    };
    const centreWeight = (b: Box) => {
      const c = toCamera(f, [0.5 * (b.min[0] + b.max[0]), 0.5 * (b.min[1] + b.max[1]), 0.5 * (b.min[2] + b.max[2])]);
      if (!(c[2] > nearDistance)) return 2;
      const x = (f.eta * c[0]) / (c[2] * f.halfW), y = (f.eta * c[1]) / (c[2] * f.halfH);
      return 1 + Math.max(0, 1 - Math.sqrt(0.5 * (x * x + y * y)));
    };

    interface Drawn extends Ranked { index: number; spacing: number }
    const final: Drawn[] = [];
    const open = new Heap<Drawn>();
    let reserved = 0, memory = 0;
    const cost = (i: number) => residentBytes(nodes[i].surfelCount);
    const place = (i: number, grown: Box) => {
      const spacing = projectedSpacing(i, grown);
      const { level, x, y, z } = nodes[i];
      const d = { index: i, spacing, priority: spacing * centreWeight(grown), level, x, y, z };
      if (spacing > params.targetPixels && nodes[i].childMask !== 0) open.push(d);
      else final.push(d);
      reserved += nodes[i].surfelCount;
      memory += cost(i);
      st.used.push(i);
    };
    ++st.visited;
    const rootGrown = culled(this.root);
    if (!rootGrown) return out;
    if (!resident(this.root)) {
      st.missing.push([this.root, Infinity]);
      return out;
    }
    place(this.root, rootGrown);
    while (open.size) {
      const d = open.pop();
      const kids = this.children[d.index];
      if (nodes[d.index].flags & kFlagChildrenInPage && kids.every((c) => c < 0)) {
        st.missingPages.push([d.index, d.priority]);
        ++st.waiting;
        final.push(d);
        continue;
      }
      const needed: [number, Box][] = [];
      let childSplats = 0, childMemory = 0;
      for (const c of kids) {
        if (c < 0) continue;
        ++st.visited;
        const grown = culled(c);
        if (!grown) continue;
        needed.push([c, grown]);
        childSplats += nodes[c].surfelCount;
        childMemory += cost(c);
      }
      if (reserved - nodes[d.index].surfelCount + childSplats > params.splatBudget || memory + childMemory > params.memoryBudget) {
        ++st.budgetLimited;
        final.push(d);
        continue;
      }
      reserved += childSplats - nodes[d.index].surfelCount;
      memory += childMemory;
      let ready = true;
      for (const [c] of needed)
        if (!resident(c)) {
          ready = false;
          st.missing.push([c, d.priority]);
        }
      if (!ready) {
        ++st.waiting;
        for (const [c] of needed) if (resident(c)) st.used.push(c);
        final.push(d);
        continue;
      }
      reserved -= childSplats;
      memory -= childMemory;
      for (const [c, grown] of needed) place(c, grown);
    }
    for (const d of final) {
      out.push({ index: d.index, projectedSpacing: d.spacing });
      st.splats += nodes[d.index].surfelCount;
    }
    return out;
  }
}

export function emptyStats(): LodStats {
  return { visited: 0, frustumCulled: 0, clipCulled: 0, backfaceCulled: 0, waiting: 0, budgetLimited: 0, splats: 0, missing: [],
           missingPages: [], used: [] };
}
