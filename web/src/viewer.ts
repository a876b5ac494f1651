// The browser viewer as a component (docs/WEB.md, "The component"): streams
// one tile set into a canvas and splats it, with the camera, settings,
// colouring, class filter and clip box set through methods, and progress,
// convergence and errors reported as events. The page (main.ts) is a thin
// client of it, as surfcast-view is of the C++ library.
//
// Redraws: one frame on the GPU at a time (a fence says when it is done), as
// soon as the GPU is free when the view changes, and while blocks stream in no
// more often than every other frame's cost, so that a slow WebGL (SwiftShader
// takes about a second for half a million splats) spends its time decoding,
// not redrawing. `state.converged` turns true once the frame that needs
// nothing more is done, and false from the moment the view changes.
//
// Following (ViewerOptions.follow), tileset.json is polled with If-None-Match;
// a new version streams beside the one drawn, adopting its unchanged nodes'
// blocks (only changed nodes are fetched), and replaces it in one frame once
// it has converged for the view, or after kMaxSwitchMs while the camera
// moves: no frame mixes two versions (the C++ client's SurfcastClient does
// the same).

import { type Camera, formatCamera, frameBox, parseCamera, viewportScale, viewRows } from "./camera.js";
import { type ColorBy, kColorByOrder, resolveColorBy } from "./coloring.js";
import { Controls } from "./controls.js";
import { crc32 } from "./crc32.js";
import { attribute, kMaxTilesetJsonBytes, type TilesetInfo } from "./format.js";
import { type Box, emptyStats } from "./lod_selection.js";
import { type DrawnNode, type FrameView, kDefaultEdgeTau, type SceneComposite, kDefaultLayers, kDefaultLowpassVariance, kDefaultZt, kMaxLayers, kNearFraction,
         type RenderMode, type RenderSettings, SplatRenderer } from "./renderer.js";
import { TileSource } from "./source.js";
import { coloringFor, type DecoderFiles, kDefaultStreamOptions, Streamer } from "./streamer.js";

// The name suffix of a wide scalar field's low part (docs/FORMAT.md, "Scalar attributes").
export const kLowPartSuffix = ":low";

export type { Box, Camera, ColorBy, RenderMode, TilesetInfo };
// "ex,ey,ez,tx,ty,tz,ux,uy,uz,fov", as surfcast-view --camera takes and the page's ?camera= keeps it.
export { formatCamera, parseCamera };
export const kRenderModes: RenderMode[] = ["points", "circles", "ewa-noprefilter", "ewa-surfel", "ewa-pixel"];

export interface ViewerOptions {
  token?: string; // sent as Authorization: Bearer with every data request
  camera?: Camera; // default: the set framed as surfcast-view frames it
  detail?: number; // refine while a node's projected spacing exceeds this many pixels (1)
  splatBudget?: number; // most splats a frame draws (5,000,000)
  gpuBudgetMiB?: number; // resident surfels' bytes, least recently used nodes evicted beyond it (512)
  blockCacheMiB?: number; // resident nodes' compressed blocks kept for recolouring (256)
  mode?: RenderMode; // ewa-pixel
  colorBy?: ColorBy; // auto: rgb where the set has it, else intensity, else elevation
  hiddenClasses?: number[];
  clip?: Box; // draw only the splats whose centre lies in this box (world coordinates, bounds included)
  opacity?: number; // multiplies every surfel's opacity, in [0, 1] (1)
  layers?: number; // translucent frames: surfaces resolved per pixel (3)
  edgeAA?: boolean; // edge antialiasing (true)
  controls?: boolean; // orbit, pan, zoom and fly with mouse, touch and keys on the canvas (true)
  // Draw every animation frame (true); false: the host draws with drawNow()
  // and sizes the canvas itself, and the canvas's WebGL2 context may be the
  // host's own (three_layer.ts).
  loop?: boolean;
  forbidFloatBlend?: boolean; // behave as a browser without float blending (tests)
  // The decode worker, with draco_decoder.js and .wasm beside it (default:
  // the three beside this module).
  workerUrl?: URL;
  // Follow the set as it changes: poll its tileset.json every this many
  // seconds and switch to each new version (0 or absent: never). The GPU
  // budget is then split in half: the version drawn, the one loading.
  follow?: number;
}

// A following viewer switches to a version loading after this long even if it
// has not converged, where the version drawn has not either (the camera keeps
// moving): coarser meanwhile, never mixed. Under a still camera it waits.
export const kMaxSwitchMs = 5000;

// What the viewer has done, updated every frame (the "change" event).
export interface ViewerState {
  converged: boolean;
  nodes: number;
  // CRC-32 of the drawn nodes' keys in key order, joined by commas:
  // surfcast-view's nodes_crc where both draw the same nodes.
  nodesCrc: number;
  splats: number;
  bytes: number;
  requests: number;
  errors: string[];
  notices: string[];
  mode: string; // the mode drawn (a browser without float blending may draw another)
  firstImageMs: number | null;
  convergedMs: number | null;
  resident: number; // nodes resident on the GPU (drawn or kept for later views)
  residentBytes: number; // the resident nodes' surfels, 32 bytes each in whole granules (lod_selection.ts)
  keptBytes: number; // the resident nodes' compressed blocks, kept for recolouring (within blockCacheMiB)
  refetched: number; // blocks fetched again for a recolouring (their kept copies had gone)
  adopted: number; // nodes of the version drawn taken from the previous version, not fetched:
  shared: number; // of those, drawn from its GPU copies (the rest decoded from its kept blocks)
  evictions: number;
  inFlight: number; // requests under way
  frames: number;
  frameMs: number; // the last frame's time on the GPU, from its draw to its fence
  camera: string; // as ?camera= and surfcast-view --camera take it
  // Following: the versions switched to since open, whether a newer one is
  // loading, and the last poll's or new version's failure ("" once one succeeds).
  version: number;
  loadingVersion: boolean;
  followError: string;
  // The version drawn is a preview of a build in progress (every Nth input
  // point: surfcast-build --preview); 0: a set. previewDone: the share of
  // its input points at full detail (the chunks built so far), in [0, 1).
  preview: number;
  previewDone: number;
}

// A surfel under the cursor (SurfcastViewer.pick).
export interface PickResult {
  node: string; // its node's key
  position: [number, number, number]; // its centre in the set's own coordinates (double)
  normal: [number, number, number];
  radius: number; // r: its own, or its node's spacing h
  color: [number, number, number] | null; // 0-255 (16-bit colour rounded) where the set stores colour
  // Every attribute the set stores beyond the fixed ones, by name, in its
  // units (stored * scale + offset): intensity, classification,
  // return_number, number_of_returns, gps_time, scan_angle, ...
  attributes: Record<string, number>;
}

// Events (CustomEvent, `detail` as said): "change" (ViewerState) after every
// selection or frame; "converged" (ViewerState) when a converged frame is
// done; "camera" (Camera) when the camera moves; "version" (ViewerState)
// when a following viewer switches to a new version; "error" (string) when the
// stream stops or an export fails; "notice" (string) for what the browser
// cannot draw as asked; with loop: false, "redraw" (null) when the view
// needs drawing again (blocks arrived, a setting changed).
export class SurfcastViewer extends EventTarget {
  readonly state: ViewerState = emptyViewerState();
  info: TilesetInfo; // of the version drawn
  private settings: RenderSettings;
  private cam: Camera;
  private colorMode: ColorBy;
  private hidden: number[];
  private detailPx: number;
  private budget: number;
  private controls?: Controls;
  private animation = 0;
  private loop: boolean;
  private disposed = false;
  private drawLast = () => {};
  // Redraw pacing (the header).
  private dirty = true;
  private urgent = true;
  private lastDraw = -Infinity;
  private frameCost = 0;
  private fence: WebGLSync | null = null;
  private fenceConverged = false;
  private readonly start = performance.now();
  private selection: { gpu: DrawnNode[]; indices: number[]; splats: number; converged: boolean; nodesCrc: number } | null = null;
  // The last frame drawn: its nodes (the streamer's indices and GPU copies) and view, for picking.
  private drawn: { gpu: DrawnNode[]; indices: number[]; view: FrameView; settings: RenderSettings } | null = null;
  private width = 1;
  private height = 1;
  // Following: the version loading and since when; the newest tileset.json
  // polled; the poll's own source and timer.
  private next: { streamer: Streamer<DrawnNode>; since: number } | null = null;
  // Why the last poll failed, and why the last version loading was dropped
  // (kept until a switch): state.followError is the first that is set.
  private pollError = "";
  private nextError = "";
  private opening = false;
  private latest = "";
  private watch: TileSource | null = null;
  private pollTimer: ReturnType<typeof setTimeout> | undefined;

  // Opens the set whose tileset.json is at `setUrl`/tileset.json. Throws an
  // Error naming what is wrong: no WebGL2, the set unreachable or malformed,
  // options out of range.
  static async open(canvas: HTMLCanvasElement, setUrl: string, options: ViewerOptions = {}): Promise<SurfcastViewer> {
    const opacity = options.opacity ?? 1, layers = options.layers ?? kDefaultLayers;
    if (!(opacity >= 0 && opacity <= 1) || !(layers >= 1 && layers <= kMaxLayers) || !Number.isInteger(layers))
      throw new Error(`opacity is in [0, 1] and layers a whole number in [1, ${kMaxLayers}]`);
    checkMode(options.mode ?? "ewa-pixel");
    checkDetail(options.detail ?? 1);
    checkSplatBudget(options.splatBudget ?? 1);
    if (options.clip) checkBox(options.clip, "clip box");
    if (!((options.gpuBudgetMiB ?? 1) >= 1) || !((options.blockCacheMiB ?? 0) >= 0))
      throw new Error("gpuBudgetMiB is at least 1 and blockCacheMiB at least 0");
    const renderer = new SplatRenderer(canvas, { forbidFloatBlend: options.forbidFloatBlend, shared: options.loop === false });
    const uploads = new SharedUploads(renderer);
    const source = new TileSource(setUrl, { token: options.token });
    let colorBy = options.colorBy ?? "auto";
    const hidden = [...(options.hiddenClasses ?? [])];
    if (!((options.follow ?? 0) >= 0)) throw new Error("follow is a number of seconds, at least 0");
    const streamer = await Streamer.open(source, uploads, decoderFiles(options),
      (info, origin) => {
        const by = resolveColorBy(colorBy, info);
        if (!kColorByOrder.includes(by as ColorBy)) throw new Error(by);
        colorBy = by as ColorBy;
        return coloringFor(info, origin, colorBy, hidden);
      }, streamOptions(options));
    return new SurfcastViewer(canvas, renderer, uploads, source, streamer, colorBy, hidden, setUrl, options);
  }

  private constructor(readonly canvas: HTMLCanvasElement, private renderer: SplatRenderer, private uploads: SharedUploads,
                      private source: TileSource,
                      private streamer: Streamer<DrawnNode>, colorBy: ColorBy, hidden: number[], private setUrl: string,
                      private options: ViewerOptions) {
    super();
    const info = this.info = streamer.info;
    this.colorMode = colorBy;
    this.hidden = hidden;
    this.detailPx = options.detail ?? 1;
    this.budget = options.splatBudget ?? 5_000_000;
    this.settings = {
      mode: options.mode ?? "ewa-pixel",
      shading: colorBy === "rgb" || colorBy === "intensity" ? "unlit" : "lambert",
      kernelScale: info.kernelScale,
      cutoff: 1,
      zt: kDefaultZt,
      lowpassVariance: kDefaultLowpassVariance,
      edgeAA: options.edgeAA ?? true,
      edgeTau: kDefaultEdgeTau,
      background: [1, 1, 1],
      backfaceCull: normalsOriented(info.normalSource),
      translucent: attribute(info, "opacity") !== undefined,
      opacity: options.opacity ?? 1,
      layers: options.layers ?? kDefaultLayers,
      clip: options.clip,
    };
    [this.width, this.height] = this.size();
    this.cam = options.camera ?? frameBox(info.boundsMin, info.boundsMax, this.width / this.height);
    this.state.camera = formatCamera(this.cam);
    this.noteMode();
    streamer.onChange = this.onStreamChange;
    if (options.controls ?? true) this.controls = new Controls(canvas, () => this.cam, (c) => this.setCamera(c));
    this.loop = options.loop ?? true;
    if (this.loop) this.animation = requestAnimationFrame((t) => this.frame(t));
    this.latest = streamer.json;
    if (options.follow) {
      this.watch = new TileSource(setUrl, { token: options.token });
      this.pollTimer = setTimeout(() => this.poll(), options.follow * 1000);
    }
  }

  private onStreamChange = () => {
    this.dirty = true;
    if (!this.loop) this.emit("redraw", null);  // the host draws again
  };

  // One poll of tileset.json; a new version opens beside the one drawn. A
  // failure (a host gone, a torn answer, a version whose files are gone) is
  // kept in state.followError and tried again at the next poll.
  private async poll() {
    try {
      const text = await this.watch!.changedText("tileset.json", kMaxTilesetJsonBytes);
      if (text !== null) this.latest = text;
      if (this.latest !== this.streamer.json && !this.next && !this.opening && !this.disposed) {
        this.opening = true;
        const next = await Streamer.open(new TileSource(this.setUrl, { token: this.options.token }), this.uploads,
          decoderFiles(this.options),
          (info, origin) => coloringFor(info, origin, this.colorMode, this.hidden), streamOptions(this.options));
        if (this.disposed) next.close();
        else if (next.json !== this.streamer.json) {
          next.adopt(this.streamer);
          next.onChange = this.onStreamChange;
          this.next = { streamer: next, since: performance.now() };
          this.latest = next.json;
          this.onStreamChange();
        } else next.close();
      }
      this.pollError = "";
    } catch (e) {
      this.pollError = (e as Error).message;
    } finally {
      this.state.followError = this.pollError || this.nextError;
      this.opening = false;
      if (!this.disposed) this.pollTimer = setTimeout(() => this.poll(), this.options.follow! * 1000);
    }
  }

  // For hosts that draw (loop: false): selects the nodes for `camera` at the
  // drawing buffer's size, which also queues what the view still needs,
  // and draws them at once, over and against `composite`'s scene where
  // given. The "change" event says when arriving blocks call for another
  // draw; the state is converged after a draw that needed nothing more.
  drawNow(camera: Camera, composite?: SceneComposite) {
    const gl = this.renderer.gl;
    this.cam = camera;
    this.state.camera = formatCamera(camera);
    [this.width, this.height] = [gl.drawingBufferWidth, gl.drawingBufferHeight];
    this.dirty = false;
    const selection = this.select();
    this.draw(selection, composite);
    if (selection.converged && !this.state.converged) {
      this.state.converged = true;
      this.state.convergedMs ??= performance.now() - this.start;
      this.emit("converged", this.state);
    } else if (!selection.converged) this.state.converged = false;
  }

  get camera(): Camera { return this.cam; }
  setCamera(camera: Camera) {
    this.cam = camera;
    this.state.camera = formatCamera(camera);
    this.changed();
    this.emit("camera", camera);
  }
  get mode(): RenderMode { return this.settings.mode; }
  setMode(mode: RenderMode) {
    checkMode(mode);
    this.settings.mode = mode;
    this.noteMode();
    this.changed();
  }
  get detail(): number { return this.detailPx; }
  setDetail(pixels: number) {
    checkDetail(pixels);
    this.detailPx = pixels;
    this.changed();
  }
  get splatBudget(): number { return this.budget; }
  setSplatBudget(splats: number) {
    checkSplatBudget(splats);
    this.budget = splats;
    this.changed();
  }
  // The colourings this set can show (rgb, intensity, elevation, classification, return).
  get colorings(): ColorBy[] { return kColorByOrder.filter((by) => resolveColorBy(by, this.info) === by); }
  get colorBy(): ColorBy { return this.colorMode; }
  setColorBy(by: ColorBy) {
    const resolved = resolveColorBy(by, this.info);
    if (!kColorByOrder.includes(resolved as ColorBy)) throw new Error(resolved);
    this.colorMode = resolved as ColorBy;
    this.settings.shading = this.colorMode === "rgb" || this.colorMode === "intensity" ? "unlit" : "lambert";
    this.recolor();
  }
  get hiddenClasses(): number[] { return [...this.hidden]; }
  setHiddenClasses(classes: number[]) {
    this.hidden = [...classes];
    this.recolor();
  }
  get clip(): Box | undefined { return this.settings.clip; }
  setClip(box: Box | undefined) {
    if (box) checkBox(box, "clip box");
    this.settings.clip = box;
    this.changed();
  }

  // The input points in `box` of the classes shown, as LAZ, from
  // surfcast-serve's export route (docs/PROTOCOL.md). Without a box, every
  // point: the request has no bbox (the set's bounds as one would cut leaf
  // points that round to just outside them).
  async exportLaz(box?: Box): Promise<Blob> {
    const shown = this.hidden.length ? [...this.info.statistics.classCounts.keys()].filter((c) => !this.hidden.includes(c))
                                     : undefined;
    try {
      if (shown?.length === 0) throw new Error("every class is hidden: no points to export");
      return await this.source.exportLaz(box, shown);
    } catch (e) {
      const message = `export: ${(e as Error).message}`;
      this.emit("error", message);
      throw new Error(message);
    }
  }

  // The surfel under canvas point (x, y), in CSS pixels from its top left,
  // in the last frame drawn: the nearest splat there by its EWA footprint,
  // whatever the mode draws (an id pass on the GPU, read back), its
  // attributes decoded again from its node's block. Null where no splat
  // covers the point, and while the frame drawn is out of date (a node of it
  // evicted or recoloured since: its surfels are no longer those drawn).
  async pick(x: number, y: number): Promise<PickResult | null> {
    const d = this.drawn;
    if (!d || d.indices.some((i, k) => this.streamer.residentNode(i)?.gpu !== d.gpu[k])) return null;
    const sx = this.canvas.clientWidth > 0 ? this.canvas.width / this.canvas.clientWidth : 1;
    const sy = this.canvas.clientHeight > 0 ? this.canvas.height / this.canvas.clientHeight : 1;
    const hit = this.renderer.pick(d.gpu, d.view, d.settings, Math.floor(x * sx), Math.floor(y * sy));
    if (!hit) return null;
    const i = d.indices[hit.node];
    const s = await this.streamer.surfel(i, hit.surfel);
    if (!s) return null;
    const o = this.streamer.origin;
    const attributes: Record<string, number> = {};
    for (const a of this.info.attributes) if (a.name in s.raw) attributes[a.name] = s.raw[a.name] * a.scale + a.offset;
    // A wide field is its two attributes' sum (docs/FORMAT.md, "Scalar attributes").
    for (const name of Object.keys(attributes))
      if (name.endsWith(kLowPartSuffix) && name.slice(0, -kLowPartSuffix.length) in attributes) {
        attributes[name.slice(0, -kLowPartSuffix.length)] += attributes[name];
        delete attributes[name];
      }
    return { node: this.streamer.selector.nodes[i].key, position: [s.position[0] + o[0], s.position[1] + o[1], s.position[2] + o[2]],
             normal: s.normal, radius: s.radius, color: s.color ? s.color.map((c) => Math.round(c * 255)) as PickResult["color"] : null,
             attributes };
  }

  // For benchmarks: draws the current selection n times, each waited for
  // (a one-pixel read: gl.finish does not wait in Chromium), and returns the
  // mean milliseconds per frame.
  timeFrames(n: number): number {
    const gl = this.renderer.gl, pixel = new Uint8Array(4);
    const sync = () => gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
    this.drawLast();
    sync();
    const t0 = performance.now();
    for (let i = 0; i < n; ++i) {
      this.drawLast();
      sync();
    }
    return (performance.now() - t0) / n;
  }

  // Stops drawing and streaming, lets go of the canvas's controls, and frees
  // the GPU memory and decode workers.
  dispose() {
    this.disposed = true;
    cancelAnimationFrame(this.animation);
    clearTimeout(this.pollTimer);
    this.controls?.dispose();
    this.streamer.onChange = () => {};
    this.streamer.close();
    this.next?.streamer.close();
    this.next = null;
    if (this.fence) this.renderer.gl.deleteSync(this.fence);
    this.renderer.dispose();
    this.drawn = this.selection = null;
  }

  private emit(type: string, detail: unknown) {
    this.dispatchEvent(new CustomEvent(type, { detail }));
  }
  private changed() {
    this.urgent = this.dirty = true;
    this.state.converged = false;
    if (!this.loop) this.emit("redraw", null);  // the host draws again
  }
  private recolor() {
    this.changed();
    this.streamer.recolor(coloringFor(this.info, this.streamer.origin, this.colorMode, this.hidden));
    const next = this.next?.streamer;
    next?.recolor(coloringFor(next.info, next.origin, this.colorMode, this.hidden));
  }
  private notice(message: string) {
    if (this.state.notices.includes(message)) return;
    this.state.notices.push(message);
    this.emit("notice", message);
  }
  private error(message: string) {
    if (this.state.errors.includes(message)) return;
    this.state.errors.push(message);
    this.emit("error", message);
  }
  private noteMode() {
    const s = this.settings, hasWeights = this.info.weights !== "none";
    this.state.mode = this.renderer.effectiveMode(s.mode, hasWeights);
    if ((s.translucent || s.opacity < 1) && !this.renderer.floatBlend)
      this.notice("this browser cannot blend float targets (EXT_float_blend): transparency is drawn opaque");
    if (this.state.mode !== s.mode)
      this.notice(`this browser cannot blend float targets (EXT_float_blend): drawing ${this.state.mode} instead of ${s.mode}` +
                  (hasWeights ? "" : ", as the set was built without weights (surfcast-build --weights analytic)"));
  }
  private size(): [number, number] {
    const dpr = window.devicePixelRatio || 1;
    return [Math.max(1, Math.round(this.canvas.clientWidth * dpr)), Math.max(1, Math.round(this.canvas.clientHeight * dpr))];
  }

  // A new selection, which also queues the fetches the view needs.
  private select() {
    const params = { targetPixels: this.detailPx, frustumCulling: true, backfaceCulling: this.settings.backfaceCull,
                     splatBudget: this.budget, memoryBudget: Infinity, clip: this.settings.clip };
    let lod = emptyStats();
    let selected = this.streamer.update(this.cam, this.width, this.height, params, lod);
    if (this.next) {
      const next = this.next.streamer, nextLod = emptyStats();
      const nextSelected = next.update(this.cam, this.width, this.height, params, nextLod);
      if (next.stats.gaveUp) {  // drawn as before; the next poll opens the newest again
        this.nextError = next.stats.lastError;
        this.state.followError = this.pollError || this.nextError;
        next.onChange = () => {};
        next.close();
        this.next = null;
      } else if (converged(next, nextLod) || (!converged(this.streamer, lod) && performance.now() - this.next.since > kMaxSwitchMs)) {
        next.adopt(null);
        this.streamer.onChange = () => {};
        this.streamer.close();
        this.streamer = next;
        this.next = null;
        this.nextError = "";
        this.state.followError = this.pollError;
        // The new version's defaults (the user's mode, colouring and clip stay).
        this.info = next.info;
        this.settings.kernelScale = next.info.kernelScale;
        this.settings.backfaceCull = normalsOriented(next.info.normalSource);
        this.settings.translucent = attribute(next.info, "opacity") !== undefined;
        this.noteMode();
        [selected, lod] = [nextSelected, nextLod];
        ++this.state.version;
        this.emit("version", this.state);
      }
    }
    const streamer = this.streamer;
    // Drawn in key order, as the Vulkan client draws them. Every selected
    // node is resident until the next update (eviction spares what a view uses).
    const nodes = streamer.selector.nodes;
    selected.sort((a, b) => {
      const p = nodes[a.index], q = nodes[b.index];
      return p.level - q.level || p.x - q.x || p.y - q.y || p.z - q.z;
    });
    const gpu: DrawnNode[] = [], indices: number[] = [];
    const keys: string[] = [];
    let splats = 0;
    for (const s of selected) {
      const r = streamer.residentNode(s.index);
      if (!r) continue;
      gpu.push(r.gpu);
      indices.push(s.index);
      keys.push(nodes[s.index].key);
      splats += r.count;
    }
    const st = streamer.stats;
    // A version loading is wanted too.
    const done = converged(streamer, lod) && !this.next;
    if (st.gaveUp && !this.next) this.error(st.lastError);
    Object.assign(this.state, { bytes: st.bytes, requests: st.requests, resident: st.resident, residentBytes: st.residentBytes, keptBytes: st.keptBytes,
                                refetched: st.refetched, adopted: st.adopted, shared: st.shared, evictions: st.evictions, inFlight: st.inFlight,
                                loadingVersion: this.next !== null, preview: this.info.previewStride,
                                previewDone: this.info.previewDone });
    return { gpu, indices, splats, converged: done, nodesCrc: crc32(new TextEncoder().encode(keys.join(","))) };
  }

  // Each animation frame: a new selection whenever something changed, and a
  // draw of the latest one when the GPU is free and the pacing allows.
  // Selecting never waits for drawing: on a slow WebGL the stream keeps going
  // while a frame renders.
  private frame(now: number) {
    if (this.disposed) return;
    const gl = this.renderer.gl, state = this.state;
    if (this.fence && gl.getSyncParameter(this.fence, gl.SYNC_STATUS) === gl.SIGNALED) {
      gl.deleteSync(this.fence);
      this.fence = null;
      this.frameCost = performance.now() - this.lastDraw;
      state.frameMs = this.frameCost;
      if (this.fenceConverged && !this.dirty && !this.selection) {
        state.convergedMs ??= performance.now() - this.start;
        state.converged = true;
        this.emit("converged", state);
      }
    }
    const [w, h] = this.size();
    if (w !== this.width || h !== this.height) {
      [this.width, this.height] = [w, h];
      this.urgent = this.dirty = true;
    }
    if (this.dirty) {
      this.dirty = false;
      state.converged = false;
      this.selection = this.select();
      this.emit("change", state);
    }
    if (this.selection && !this.fence && (this.urgent || now - this.lastDraw >= 2 * this.frameCost)) {
      this.urgent = false;
      if (this.canvas.width !== this.width || this.canvas.height !== this.height) {
        this.canvas.width = this.width;
        this.canvas.height = this.height;
      }
      const selection = this.selection;
      this.selection = null;
      this.draw(selection);
      this.fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
      gl.flush();
      this.fenceConverged = selection.converged;
    }
    this.animation = requestAnimationFrame((t) => this.frame(t));
  }

  private draw(selection: NonNullable<SurfcastViewer["selection"]>, composite?: SceneComposite) {
    const { gpu, indices, splats, nodesCrc } = selection;
    const info = this.info, state = this.state;
    const eta = viewportScale(this.cam, this.height);
    const rows = viewRows(this.cam, this.streamer.origin);
    const diagonal = Math.hypot(info.boundsMax[0] - info.boundsMin[0], info.boundsMax[1] - info.boundsMin[1],
                                info.boundsMax[2] - info.boundsMin[2]);
    const eye = Math.hypot(rows[3], rows[7], rows[11]);
    const near = Math.max(diagonal, eye) * kNearFraction || kNearFraction;
    const view = { rows, eta, near, origin: this.streamer.origin };
    this.drawn = { gpu, indices, view, settings: { ...this.settings } };
    const hasWeights = info.weights !== "none";
    this.drawLast = () => this.renderer.render(gpu, view, this.settings, hasWeights, composite);
    this.drawLast();
    this.lastDraw = performance.now();
    ++state.frames;
    Object.assign(state, { nodes: gpu.length, nodesCrc, splats });
    if (gpu.length && state.firstImageMs === null) state.firstImageMs = performance.now() - this.start;
    this.emit("change", state);
  }
}

// The renderer's node copies, each freed once released as often as uploaded
// and retained: a following viewer's two versions share the unchanged ones.
class SharedUploads {
  private refs = new Map<DrawnNode, number>();
  constructor(private renderer: SplatRenderer) {}
  upload(surfels: ArrayBuffer): DrawnNode {
    const node = this.renderer.upload(surfels);
    this.refs.set(node, 1);
    return node;
  }
  retain(node: DrawnNode) {
    this.refs.set(node, (this.refs.get(node) ?? 0) + 1);
  }
  release(node: DrawnNode) {
    const left = (this.refs.get(node) ?? 1) - 1;
    if (left > 0) this.refs.set(node, left);
    else {
      this.refs.delete(node);
      this.renderer.release(node);
    }
  }
}

// Nothing the view needs is missing from `streamer` or on its way.
function converged(streamer: Streamer<DrawnNode>, lod: ReturnType<typeof emptyStats>): boolean {
  const st = streamer.stats;
  return !st.gaveUp && lod.missing.length === 0 && lod.missingPages.length === 0 && st.inFlight === 0;
}

// The stream's budgets: a follower's GPU budget is split between two versions.
function streamOptions(options: ViewerOptions) {
  const gpu = (options.gpuBudgetMiB ?? 512) * 2 ** 20;
  return { ...kDefaultStreamOptions, memoryBudget: options.follow ? gpu / 2 : gpu,
           keptBudget: (options.blockCacheMiB ?? 256) * 2 ** 20 };
}

// The checks open() and the setters make.
function checkMode(mode: RenderMode) {
  if (!kRenderModes.includes(mode)) throw new Error(`mode ${mode}: expected ${kRenderModes.join(", ")}`);
}
function checkDetail(pixels: number) {
  if (!(pixels > 0 && Number.isFinite(pixels))) throw new Error(`detail ${pixels}: expected pixels > 0`);
}
function checkSplatBudget(splats: number) {
  if (!(splats >= 1)) throw new Error(`splat budget ${splats}: expected at least 1`);
}
function checkBox(box: Box, what: string) {
  for (let a = 0; a < 3; ++a)
    if (!Number.isFinite(box.min[a]) || !Number.isFinite(box.max[a]) || box.min[a] > box.max[a])
      throw new Error(`${what}: axis ${"xyz"[a]} from ${box.min[a]} to ${box.max[a]}`);
}

// The decode worker and draco3d's decoder, beside this module unless the
// options name a worker. Each URL is the literal `new URL("./x", import.meta.url)`:
// a static host resolves it beside the module, and bundlers that know the
// pattern emit the file with the bundle (docs/WEB.md, "The npm package").
function decoderFiles(options: ViewerOptions): DecoderFiles {
  if (options.workerUrl) return { worker: options.workerUrl };
  return {
    worker: new URL("./decode_worker.js", import.meta.url),
    decoder: { draco: new URL("./draco_decoder.js", import.meta.url).href, wasm: new URL("./draco_decoder.wasm", import.meta.url).href },
  };
}

// "X0,Y0,Z0,X1,Y1,Z1", as surfcast-view's --clip and the export route's bbox
// take it; `what` names it in errors.
export function parseBox(text: string, what: string): Box {
  const items = text.split(",");
  // Decimal numbers only: stricter than C++'s strtod, which also takes hex and leading blanks.
  const v = items.map((s) => (/^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/.test(s) ? Number(s) : NaN));
  if (v.length !== 6 || !v.every(Number.isFinite))
    throw new Error(`${what} ${text}: six numbers wanted (xmin,ymin,zmin,xmax,ymax,zmax)`);
  const box: Box = { min: [v[0], v[1], v[2]], max: [v[3], v[4], v[5]] };
  for (let a = 0; a < 3; ++a)
    if (box.min[a] > box.max[a]) throw new Error(`${what} ${text}: its minimum exceeds its maximum on axis ${"xyz"[a]}`);
  return box;
}
export const formatBox = (b: Box) => [...b.min, ...b.max].join(",");

// A viewer's state before anything is drawn.
export function emptyViewerState(): ViewerState {
  return { converged: false, nodes: 0, nodesCrc: 0, splats: 0, bytes: 0, requests: 0, errors: [], notices: [], mode: "",
           firstImageMs: null, convergedMs: null, resident: 0, residentBytes: 0, keptBytes: 0, refetched: 0, adopted: 0, shared: 0, evictions: 0,
           inFlight: 0, frames: 0, frameMs: 0, camera: "", version: 0, loadingVersion: false, followError: "",
           preview: 0, previewDone: 0 };
}

function normalsOriented(source: string): boolean {
  return source !== "" && source.split("+").every((p) => p === "input" || p === "estimated-scan-origin");
}
