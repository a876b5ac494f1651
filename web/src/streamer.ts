// A tile set streamed into the browser (the twin of client/stream/streamer):
// opening fetches tileset.json, hierarchy.bin's header and page table, and
// page 0; each update() traverses from the root (LodSelector), and fetches
// what the view still needs, pages first, then nodes coarsest gap first, at
// most `connections` requests at a time (batches of nodes where tileset.json's
// answer offers them, as surfcast-serve's does; Range requests elsewhere). Blocks are checked (CRC, Draco
// header) and decoded in Web Workers; the surfels are uploaded as they
// arrive. Transient faults (source.ts) are retried with backoff (0.1 s
// doubling to 5 s) up to maxTries times; permanent ones (other HTTP errors, a
// block that fails its CRC or decoding, a page that fails its checks) are
// not. Either way the stream then stops, naming the node and why. Residency
// has a byte budget: beyond it the least recently used nodes that the view
// does not use are evicted. Resident nodes keep their compressed blocks up to
// keptBudget bytes, so that recolor() decodes them again without fetching;
// beyond it the least recently used nodes' blocks go, and a recolour fetches
// those again (as the C++ stream does). A newer version of the set (a
// follower's: viewer.ts) adopts an older one's kept blocks: a node with the
// same key, block CRC and size is decoded from them, not fetched; where
// decoding would give the surfels the older one has resident (equal records
// and decodingKey), their GPU copy is shared (Uploader.retain), not decoded.

import type { Camera } from "./camera.js";
import type { ColoringSpec, DecodeJob, DecodeResult, DecoderUrls, PickedSurfel } from "./block_decode.js";
import { attribute, blockLayout, FormatError, indexBytes, kFlagEdgeWeights, kFlagHasRadius, kMaxTilesetJsonBytes,
         type HierarchyIndex, type NodeRecord, nodeEdge, nodeMin, parseTileset, placeBlock, readHierarchyIndex, readHierarchyPage,
         type TilesetInfo, type Vec3 } from "./format.js";
import { emptyStats, type LodParams, LodSelector, type LodStats, residentBytes, type SelectedNode } from "./lod_selection.js";
import { HttpError, TileSource } from "./source.js";

export interface StreamOptions {
  connections: number;
  decoders: number;
  memoryBudget: number; // bytes of resident surfels, 32 each in whole granules (residentBytes)
  keptBudget: number; // bytes of compressed blocks kept for recolouring
  maxTries: number;
  batchNodes: number;
  batchBytes: number;
}

export const kDefaultStreamOptions: StreamOptions = {
  connections: 6,
  decoders: Math.max(1, Math.min(4, (globalThis.navigator?.hardwareConcurrency ?? 2))),
  memoryBudget: 512 * 2 ** 20,
  keptBudget: 256 * 2 ** 20, // every resident node's, for a full memoryBudget (blocks take about a third of it)
  maxTries: 8,
  batchNodes: 32,
  batchBytes: 512 << 10,
};

export interface Resident<T> {
  gpu: T;
  count: number; // surfels drawn (after class filters)
  lastUsed: number;
  block: Uint8Array | null; // compressed, as fetched: recolor() decodes it again (null: gone, beyond keptBudget)
}

// What the GPU side does with arriving and evicted nodes. A copy a second
// version's node shares (retain) is freed once released as often as retained
// and uploaded.
export interface Uploader<T> {
  upload(surfels: ArrayBuffer): T;
  release(gpu: T): void;
  retain?(gpu: T): void;
}

async function withRetries<R>(tries: number, attempt: () => Promise<R>, stopped: () => boolean): Promise<R> {
  let delay = 100;
  for (let i = 1; ; ++i) {
    try {
      return await attempt();
    } catch (e) {
      const transient = e instanceof HttpError && e.transient;
      if (!transient || i >= tries || stopped()) throw e;
      await new Promise((r) => setTimeout(r, delay));
      delay = Math.min(2 * delay, 5000);
    }
  }
}

// The decode worker's script, and draco3d's decoder (the worker's own
// default without: draco_decoder.js and .wasm beside the worker).
export interface DecoderFiles {
  worker: URL;
  decoder?: DecoderUrls;
}

class DecoderPool {
  private workers: Worker[] = [];
  private pending = new Map<number, (r: DecodeResult) => void>();
  private next = 0;
  private id = 0;
  constructor(files: DecoderFiles, count: number, onError: (message: string) => void) {
    for (let i = 0; i < count; ++i) {
      const w = new Worker(files.worker);
      if (files.decoder) w.postMessage({ decoder: files.decoder });
      w.onmessage = (e: MessageEvent<DecodeResult>) => {
        const done = this.pending.get(e.data.id);
        this.pending.delete(e.data.id);
        done?.(e.data);
      };
      w.onerror = (e) => {
        this.settle(`decode worker: ${e.message}`);  // its jobs will never answer
        onError(`decode worker: ${e.message}`);
      };
      this.workers.push(w);
    }
  }
  // Answers every pending job with an error.
  private settle(error: string) {
    for (const [id, done] of this.pending) done({ id, error });
    this.pending.clear();
  }
  decode(job: Omit<DecodeJob, "id">): Promise<DecodeResult> {
    const id = ++this.id;
    const w = this.workers[this.next++ % this.workers.length];
    return new Promise((resolve) => {
      this.pending.set(id, resolve);
      w.postMessage({ ...job, id }, [job.blob]);
    });
  }
  terminate() {
    for (const w of this.workers) w.terminate();
    this.settle("the stream was closed");
  }
}

export interface StreamStats {
  requests: number;
  bytes: number;
  pages: number;
  nodesFetched: number;
  inFlight: number;
  resident: number;
  residentBytes: number;
  keptBytes: number; // the resident nodes' compressed blocks, kept for recolouring (within keptBudget)
  refetched: number; // blocks fetched again to recolour nodes whose kept blocks had gone
  adopted: number; // nodes an older version had (adopt()), not fetched: decoded from its kept block, or
  shared: number; // drawn from its GPU copy (Uploader.retain), not decoded
  evictions: number;
  failures: number;
  lastError: string;
  gaveUp: boolean;
}

export class Streamer<T> {
  readonly info: TilesetInfo;
  readonly origin: Vec3; // the render origin: the bounds' centre
  selector: LodSelector;
  private index: HierarchyIndex;
  private resident = new Map<number, Resident<T>>();
  private inFlight = new Set<number>();
  private pagesInFlight = new Set<number>();
  private tries = new Map<number, number>();
  private pageTries = new Map<number, number>();
  private requestsInFlight = 0;
  private decoders: DecoderPool;
  private clock = 0;
  private generation = 0; // of the colouring: what was decoded with an older one is decoded again
  private recoloring = new Set<number>(); // resident nodes being decoded again with a new colouring
  private refetchQueue: number[] = []; // of those, the ones whose blocks are to be fetched again
  private layout: { columns: boolean; extra: string[]; extraBits: number[] };
  private donor: Streamer<T> | null = null;
  coloring: ColoringSpec;
  readonly stats: StreamStats = { requests: 0, bytes: 0, pages: 1, nodesFetched: 0, inFlight: 0, resident: 0,
                                  residentBytes: 0, keptBytes: 0, refetched: 0, adopted: 0, shared: 0, evictions: 0, failures: 0, lastError: "",
                                  gaveUp: false };
  onChange: () => void = () => {};

  // `json`: tileset.json as opened (the version this stream shows).
  private constructor(readonly source: TileSource, readonly json: string, info: TilesetInfo, origin: Vec3, index: HierarchyIndex,
                      page0: NodeRecord[], private uploader: Uploader<T>, decoderFiles: DecoderFiles, coloring: ColoringSpec,
                      readonly options: StreamOptions) {
    this.info = info;
    this.index = index;
    this.origin = origin;
    this.selector = new LodSelector(info, page0);
    this.layout = blockLayout(info);
    this.coloring = coloring;
    this.decoders = new DecoderPool(decoderFiles, options.decoders, (m) => this.fail(m));
  }

  // Opens the set at `source`, or throws an Error saying why it cannot be shown.
  static async open<T>(source: TileSource, uploader: Uploader<T>, decoderFiles: DecoderFiles,
                       coloring: (info: TilesetInfo, origin: Vec3) => ColoringSpec,
                       options: StreamOptions = kDefaultStreamOptions): Promise<Streamer<T>> {
    const stop = () => false;
    const json = await withRetries(options.maxTries, () => source.text("tileset.json", kMaxTilesetJsonBytes), stop);
    const info = parseTileset(json, `${source.base}/tileset.json`);
    source.version = info.hierarchyCrc;
    const what = `${source.base}/${info.hierarchyFile}`;
    const head = await withRetries(options.maxTries, () => source.range(info.hierarchyFile, 0, Math.min(info.hierarchyBytes, 32 + 16 * info.hierarchyPages)), stop);
    if (head.length < 32 || indexBytes(head) !== head.length)
      throw new FormatError(`${what}: its header does not declare the ${info.hierarchyPages} pages tileset.json lists`);
    const index = readHierarchyIndex(head, info.hierarchyBytes, what);
    const p0 = index.pages[0];
    if (!p0) throw new FormatError(`${what}: no pages`);
    const bytes = await withRetries(options.maxTries, () => source.range(info.hierarchyFile, p0.offset, p0.records * 64), stop);
    const page0 = readHierarchyPage(index, 0, bytes, "0-0-0-0", info.blocksBytes, what);
    const origin = [0, 1, 2].map((a) => 0.5 * (info.boundsMin[a] + info.boundsMax[a])) as Vec3;
    return new Streamer(source, json, info, origin, index, page0, uploader, decoderFiles, coloring(info, origin), options);
  }

  isResident = (i: number) => this.resident.has(i);

  // Decode the nodes `donor` (another version of this set) holds unchanged
  // from its kept blocks rather than fetch them; null: no longer.
  adopt(donor: Streamer<T> | null) {
    this.donor = donor;
  }
  // What decoding a node gives besides its record and block: the origin,
  // the root cube, the colour bits, the attributes and the colouring with
  // what it reads (the C++ client's decodingKey, surfel_set.h).
  get decodingKey(): string {
    const i = this.info, c = this.coloring;
    const reads = c.by === "intensity" ? [c.intensityScale, c.intensityOffset, c.intensityP2, c.intensityP98]
      : c.by === "elevation" ? [c.originZ, c.elevationMin, c.elevationMax] : [];
    return JSON.stringify([this.origin, i.rootMin, i.rootEdge, i.colorBits, i.weights, this.layout.extra, c.by, c.hiddenClasses, reads]);
  }
  // This set's resident node with the record's key, if its block has the
  // record's CRC and size and is kept: the block, and the GPU copy where it
  // holds the surfels a set of decoding key `key` decodes for the record.
  kept(n: NodeRecord, key: string): { block: Uint8Array; resident: Resident<T> | null } | null {
    const i = this.selector.find(n.key);
    if (i === undefined) return null;
    const mine = this.selector.nodes[i], r = this.resident.get(i);
    if (mine.blockCrc !== n.blockCrc || mine.blockSize !== n.blockSize || !r?.block) return null;
    const decoding = kFlagHasRadius | kFlagEdgeWeights;
    const same = this.recoloring.size === 0 && key === this.decodingKey && mine.surfelCount === n.surfelCount &&
      mine.spacing === n.spacing && mine.positionBits === n.positionBits && ((mine.flags ^ n.flags) & decoding) === 0;
    return { block: r.block, resident: same ? r : null };
  }
  // The wanted nodes the donor holds unchanged: their GPU copies shared, or
  // their kept blocks decoded at once; the rest are to be fetched.
  private adoptKept(wanted: number[]): number[] {
    const donor = this.donor, retain = this.uploader.retain?.bind(this.uploader);
    if (!donor) return wanted;
    const key = this.decodingKey;
    return wanted.filter((i) => {
      const had = donor.kept(this.selector.nodes[i], key);
      if (!had) return true;
      ++this.stats.adopted;
      if (had.resident && retain) {
        retain(had.resident.gpu);
        this.resident.set(i, { gpu: had.resident.gpu, count: had.resident.count, lastUsed: this.clock, block: had.block });
        ++this.stats.shared;
        this.onChange();
        return false;
      }
      this.inFlight.add(i);
      this.decodeNode(i, had.block, false, false, true).catch((e) => this.noteFailure(i, e as Error));
      return false;
    });
  }

  private fail(message: string) {
    if (this.stats.gaveUp) return;
    this.stats.gaveUp = true;
    this.stats.lastError = message;
    this.dropRefetches();
    this.onChange();
  }

  // The nodes to draw now, and what the view still needs queued for fetching.
  update(camera: Camera, width: number, height: number, params: LodParams, lod: LodStats = emptyStats()): SelectedNode[] {
    const selected = this.selector.select(camera, width, height, { ...params, memoryBudget: this.options.memoryBudget }, this.isResident, lod);
    const now = ++this.clock;
    for (const i of lod.used) {
      const r = this.resident.get(i);
      if (r) r.lastUsed = now;
    }
    this.evict(now);
    if (!this.stats.gaveUp) {
      for (const [node] of lod.missingPages.sort((a, b) => b[1] - a[1])) this.fetchPage(node);
      const wanted = lod.missing.filter(([i]) => !this.inFlight.has(i)).sort((a, b) => b[1] - a[1]).map(([i]) => i);
      this.pumpRefetches();  // recolourings first: those nodes are on screen
      this.fetchNodes(this.adoptKept(wanted));
    }
    this.stats.inFlight = this.inFlight.size + this.pagesInFlight.size + this.recoloring.size;
    this.stats.requests = this.source.requests;
    this.stats.bytes = this.source.bytes;
    return selected;
  }

  // Residency counts each node as the selection does (residentBytes: all
  // its surfels, in whole granules), as the C++ stream does.
  private evict(now: number) {
    const cost = (i: number) => residentBytes(this.selector.nodes[i].surfelCount);
    let bytes = 0;
    for (const i of this.resident.keys()) bytes += cost(i);
    if (bytes > this.options.memoryBudget) {
      const old = [...this.resident.entries()].filter(([, r]) => r.lastUsed < now).sort((a, b) => a[1].lastUsed - b[1].lastUsed);
      for (const [i, r] of old) {
        if (bytes <= this.options.memoryBudget) break;
        this.uploader.release(r.gpu);
        this.resident.delete(i);
        bytes -= cost(i);
        ++this.stats.evictions;
      }
    }
    this.stats.resident = this.resident.size;
    this.stats.residentBytes = bytes;
    let kept = 0;
    for (const r of this.resident.values()) kept += r.block?.byteLength ?? 0;
    if (kept > this.options.keptBudget) {
      const old = [...this.resident.values()].filter((r) => r.block).sort((a, b) => a.lastUsed - b.lastUsed);
      for (const r of old) {
        if (kept <= this.options.keptBudget) break;
        kept -= r.block!.byteLength;
        r.block = null;
      }
    }
    this.stats.keptBytes = kept;
  }

  // A node's block, from the file of the set that holds it.
  private async blockRange(n: NodeRecord): Promise<Uint8Array> {
    const place = placeBlock(this.info.blocksParts, n.blockOffset, n.blockSize);
    return this.source.range(place.file, place.offset, n.blockSize);
  }

  private fetchPage(node: number) {
    const record = this.selector.nodes[node];
    const page = record.childPage;
    if (this.pagesInFlight.has(page) || this.requestsInFlight >= this.options.connections) return;
    this.pagesInFlight.add(page);
    ++this.requestsInFlight;
    const e = this.index.pages[page];
    const what = `${this.source.base}/${this.info.hierarchyFile}`;
    const attempt = async () => {
      const bytes = await this.source.range(this.info.hierarchyFile, e.offset, e.records * 64);
      return readHierarchyPage(this.index, page, bytes, record.key, this.info.blocksBytes, what);
    };
    withRetries(this.options.maxTries, attempt, () => this.stats.gaveUp)
      .then((records) => {
        this.selector.addNodes(records);
        ++this.stats.pages;
      })
      .catch((err) => this.fail((err as Error).message))
      .finally(() => {
        this.pagesInFlight.delete(page);
        --this.requestsInFlight;
        this.onChange();
      });
  }

  private fetchNodes(wanted: number[]) {
    let at = 0;
    while (at < wanted.length && this.requestsInFlight < this.options.connections) {
      const group: number[] = [];
      let bytes = 0;
      const most = Math.max(1, Math.min(this.options.batchNodes, this.source.batchNodes));
      while (at < wanted.length && group.length < most && (group.length === 0 || bytes < this.options.batchBytes)) {
        const i = wanted[at++];
        group.push(i);
        bytes += this.selector.nodes[i].blockSize;
      }
      for (const i of group) this.inFlight.add(i);
      ++this.requestsInFlight;
      const records = group.map((i) => this.selector.nodes[i]);
      const request = group.length > 1 ? this.source.blobs(records)
        : this.blockRange(records[0]).then((b) => [b]);
      // The connection is free once the bytes are in; decoding goes on in the workers.
      let open = true;
      const release = () => {
        if (!open) return;
        open = false;
        --this.requestsInFlight;
        this.onChange();
      };
      request
        .then((blobs) => {
          release();
          return Promise.all(group.map((i, k) => this.decodeNode(i, blobs[k])));
        })
        .catch((err) => group.forEach((i) => this.noteFailure(i, err as Error)))
        .finally(release);
    }
  }

  // Decodes node i's block with the current colouring (again, if the
  // colouring changes meanwhile) and makes it resident, or, for a resident
  // node being recoloured, replaces its surfels on the GPU.
  // The decoding of node i's block (a copy of it, which the worker takes)
  // with the current colouring.
  private job(i: number, block: Uint8Array): Omit<DecodeJob, "id"> {
    const n = this.selector.nodes[i];
    const min = nodeMin(this.info, n);
    return {
      key: n.key, blob: block.slice().buffer, crc: n.blockCrc, points: n.surfelCount, positionBits: n.positionBits,
      min: [min[0] - this.origin[0], min[1] - this.origin[1], min[2] - this.origin[2]], edge: nodeEdge(this.info, n.level),
      spacing: n.spacing, hasRadius: !!(n.flags & kFlagHasRadius), hasEdgeWeights: !!(n.flags & kFlagEdgeWeights),
      colorBits: this.info.colorBits, weights: this.info.weights !== "none", ...this.layout, coloring: this.coloring,
    };
  }

  private async decodeNode(i: number, blob: Uint8Array, recolor = false, refetched = false, adopted = false) {
    const generation = this.generation;
    const n = this.selector.nodes[i];
    // The worker takes a copy (transferred); the block stays here, its own
    // bytes (not a view of a whole batch response).
    const block = blob.byteOffset === 0 && blob.byteLength === blob.buffer.byteLength ? blob : blob.slice();
    const result = await this.decoders.decode(this.job(i, block));
    if (result.error || !result.surfels) {
      if (!recolor) this.noteFailure(i, new Error(result.error ?? "decoding failed"));
      else if (refetched) {  // a block fetched again fails like any fetch: the stream stops
        this.recoloring.delete(i);
        this.fail(`node ${n.key}: ${result.error ?? "decoding failed"}`);
      } else this.recolorFailed(i, result.error ?? "decoding failed");
      return;
    }
    const old = this.resident.get(i);
    if (!this.stats.gaveUp && generation !== this.generation && (!recolor || old)) {
      await this.decodeNode(i, block, recolor, refetched, adopted);  // recoloured meanwhile: its surfels would show the old colouring
      return;
    }
    // A recolouring owns only its place in `recoloring`: the node may be
    // fetched again meanwhile (evicted), with its own tries.
    if (recolor) this.recoloring.delete(i);
    else {
      this.inFlight.delete(i);
      this.tries.delete(i);
    }
    // Not kept when the stream stopped, nor a recolouring of a node evicted meanwhile.
    if (!this.stats.gaveUp && (!recolor || old)) {
      if (old) this.uploader.release(old.gpu);
      this.resident.set(i, { gpu: this.uploader.upload(result.surfels), count: result.count ?? 0,
                             lastUsed: old?.lastUsed ?? this.clock, block });
      if (!recolor && !adopted) ++this.stats.nodesFetched;
    }
    this.onChange();
  }

  private noteFailure(i: number, err: Error) {
    this.inFlight.delete(i);
    ++this.stats.failures;
    const tries = (this.tries.get(i) ?? 0) + 1;
    this.tries.set(i, tries);
    const transient = err instanceof HttpError && err.transient;
    this.stats.lastError = err.message;
    if (!transient || tries >= this.options.maxTries) {
      this.fail(`node ${this.selector.nodes[i].key}: ${err.message}${tries > 1 ? ` (after ${tries} tries)` : ""}`);
      return;
    }
    // Backoff: the node is asked for again by a later update().
    this.inFlight.add(i);
    setTimeout(() => {
      this.inFlight.delete(i);
      this.onChange();
    }, Math.min(100 * 2 ** (tries - 1), 5000));
  }

  // Every resident node decoded again from its kept block with another
  // colouring; each is drawn with its old surfels until its new ones arrive,
  // and the stream counts them in flight until then.
  // Blocks that went (keptBudget) are fetched again, most recently used
  // first, in batches within the connection limit (pumpRefetches).
  recolor(coloring: ColoringSpec) {
    this.coloring = coloring;
    ++this.generation;
    const missing: [number, number][] = [];
    for (const [i, r] of this.resident) {
      if (this.recoloring.has(i)) continue;  // decoded again when it finishes
      if (r.block) {
        this.recoloring.add(i);
        this.decodeNode(i, r.block, true).catch((e) => this.recolorFailed(i, (e as Error).message));
      } else if (!this.stats.gaveUp) {
        this.recoloring.add(i);
        missing.push([r.lastUsed, i]);
      }
    }
    this.refetchQueue.push(...missing.sort((a, b) => b[0] - a[0]).map(([, i]) => i));
    this.pumpRefetches();
    this.stats.inFlight = this.inFlight.size + this.pagesInFlight.size + this.recoloring.size;
    this.onChange();
  }

  // Starts batches of refetchQueue while connections are free. A batch that
  // fails (after retries, or at once where permanent) stops the stream, as a
  // node's fetch does.
  private pumpRefetches() {
    while (this.refetchQueue.length > 0 && this.requestsInFlight < this.options.connections && !this.stats.gaveUp) {
      const group: number[] = [];
      let bytes = 0;
      const most = Math.max(1, Math.min(this.options.batchNodes, this.source.batchNodes));
      while (this.refetchQueue.length > 0 && group.length < most && (group.length === 0 || bytes < this.options.batchBytes)) {
        const i = this.refetchQueue.shift()!;
        if (!this.resident.has(i)) {  // evicted meanwhile: nothing to recolour
          this.recoloring.delete(i);
          continue;
        }
        group.push(i);
        bytes += this.selector.nodes[i].blockSize;
      }
      if (group.length === 0) continue;
      const records = group.map((i) => this.selector.nodes[i]);
      const attempt = () => group.length > 1 ? this.source.blobs(records)
        : this.blockRange(records[0]).then((b) => [b]);
      ++this.requestsInFlight;
      withRetries(this.options.maxTries, attempt, () => this.stats.gaveUp)
        .then((blobs) => {
          this.stats.refetched += group.length;
          group.forEach((i, k) => this.decodeNode(i, blobs[k], true, true).catch((e) => this.recolorFailed(i, (e as Error).message)));
        }, (e) => {
          group.forEach((i) => this.recoloring.delete(i));
          this.fail(`recolouring: nodes ${records.map((r) => r.key).join(", ")}: ${(e as Error).message}`);
        })
        .finally(() => {
          --this.requestsInFlight;
          this.pumpRefetches();
          this.onChange();
        });
    }
    if (this.stats.gaveUp) this.dropRefetches();
  }

  // The stream stopped: the nodes waiting for their blocks keep their colours.
  private dropRefetches() {
    for (const i of this.refetchQueue) this.recoloring.delete(i);
    this.refetchQueue = [];
  }

  // A recolouring that failed (bytes that decoded before, or the upload): the
  // node keeps its old surfels, and the failure is counted and kept, as the
  // C++ stream does.
  private recolorFailed(i: number, message: string) {
    this.recoloring.delete(i);
    ++this.stats.failures;
    // After the stream stopped, lastError says why.
    if (!this.stats.gaveUp) this.stats.lastError = `node ${this.selector.nodes[i].key}: recolouring: ${message}`;
    this.onChange();
  }

  residentNode(i: number) {
    return this.resident.get(i);
  }

  // The attributes of surfel k (its index in the node's packed surfels, as
  // drawn) of resident node i, decoded again from its kept block, or fetched
  // again where that went. Null where the node is not resident or is being
  // recoloured (its drawn surfels then follow the old class filter).
  async surfel(i: number, k: number): Promise<PickedSurfel | null> {
    const r = this.resident.get(i);
    if (!r || this.recoloring.has(i)) return null;
    const n = this.selector.nodes[i];
    const block = r.block ?? await this.blockRange(n);
    const result = await this.decoders.decode({ ...this.job(i, block), pick: k });
    if (result.error) throw new Error(`node ${n.key}: ${result.error}`);
    return result.picked ?? null;
  }

  close() {
    this.decoders.terminate();
    for (const r of this.resident.values()) this.uploader.release(r.gpu);
    this.resident.clear();
  }
}

export function coloringFor(info: TilesetInfo, origin: Vec3, by: ColoringSpec["by"], hiddenClasses: number[]): ColoringSpec {
  const intensity = attribute(info, "intensity");
  const st = info.statistics;
  return {
    by, originZ: origin[2], elevationMin: st.elevationMin, elevationMax: st.elevationMax,
    intensityScale: intensity?.scale ?? 1, intensityOffset: intensity?.offset ?? 0,
    intensityP2: st.intensity?.p2 ?? 0, intensityP98: st.intensity?.p98 ?? 0, hiddenClasses,
  };
}
