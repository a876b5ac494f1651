// Object-space EWA splatting on WebGL2 (Ren et al. 2002; docs/RENDERER.md):
// a visibility pass of elliptical quads pushed back by z_t writes depth, an
// accumulation pass adds colour·w, w, normal·w and the unscaled kernel into
// two float targets where the splat is within z_t of the nearest surface, and
// a resolve normalizes per pixel, shades and antialiases edges (Zwicker 2001
// §7). Points and circles draw opaque, nearest wins. Each node is one texture
// of 32-byte surfels (the GpuSurfel layout) that the vertex shader reads by
// gl_VertexID (docs/WEB.md, "Differences from the Vulkan client", says why not instancing). Translucent frames peel
// layers (Zwicker 2001 §6), as the Vulkan client does.
//
// Float blending (EXT_float_blend) is what per-pixel normalization needs.
// Without it the accumulation targets are 8-bit, where only the 2002 paper's
// per-surfel weights work (ewa-surfel, no division): that is what the
// renderer falls back to, and to circles for sets without weights. 8-bit
// targets hold no negative sums: the normal is accumulated offset to [0, 1].

import defaults from "../../common/render_defaults.json";
import { type Box, kGranuleSurfels } from "./lod_selection.js";
import { programs as shaderSources } from "surfcast:shaders";
import * as S from "./shaders.js";

export type RenderMode = "points" | "circles" | "ewa-noprefilter" | "ewa-surfel" | "ewa-pixel";
export type Shading = "unlit" | "lambert" | "phong";

export interface RenderSettings {
  mode: RenderMode;
  shading: Shading;
  kernelScale: number;
  cutoff: number;
  zt: number;
  lowpassVariance: number;
  edgeAA: boolean;
  edgeTau: number;
  background: [number, number, number];
  backfaceCull: boolean;
  // Transparency (Zwicker 2001 §6): a frame is translucent where the set
  // stores opacity or `opacity` is under 1; the ewa modes then peel `layers`
  // surfaces per pixel and blend them front to back. Points and circles stay opaque.
  translucent: boolean;
  opacity: number;
  layers: number;
  // A clip box in world coordinates: only splats whose centre lies inside
  // (bounds included) are drawn, in every mode; tested in float relative to
  // the render origin, as the Vulkan client does.
  clip?: Box;
}

// The defaults of client/render/render_settings.h (which says why each has
// its value), from the file both clients take them from.
const { renderer: kDefaults } = defaults;
export const kDefaultLayers = kDefaults.layers;
export const kMaxLayers = kDefaults.max_layers;
export const kDefaultLowpassVariance = kDefaults.lowpass_variance;
export const kDefaultEdgeTau = kDefaults.edge_tau;
export const kDefaultZt = kDefaults.zt;
export const kNearFraction = kDefaults.near_fraction;

export interface FrameView {
  rows: Float32Array; // world (relative to the render origin) -> camera, 3 x 4 row-major
  origin: [number, number, number]; // the render origin, world coordinates
  eta: number;
  near: number;
}

export interface DrawnNode {
  texture: WebGLTexture; // 2 RGBA32UI texels per surfel, kSurfelsPerRow to a row
  count: number;
}

const kSurfelsPerRow = kGranuleSurfels;  // the granule the selection counts memory in

// EXT_clip_control, which TypeScript's DOM types lack.
interface ClipControl {
  readonly LOWER_LEFT_EXT: number;
  readonly ZERO_TO_ONE_EXT: number;
  readonly CLIP_ORIGIN_EXT: number;
  readonly CLIP_DEPTH_MODE_EXT: number;
  clipControlEXT(origin: number, depth: number): void;
}

// A scene render() draws the splats into (three_layer.ts): `depth` fills the
// visibility pass's depth before the splats are drawn (the scene's surfaces
// as this renderer's reversed-Z depth, near / z for `near`), so that they
// hide the splats behind them; `background` draws the scene's colour into the
// canvas, over which the resolve blends the splats by their coverage, so
// that splats in front hide the scene. Each leaves the GL state to render().
export interface SceneComposite {
  depth(gl: WebGL2RenderingContext, near: number): void;
  background(gl: WebGL2RenderingContext): void;
}

export class RendererError extends Error {}

function compile(gl: WebGL2RenderingContext, type: number, source: string): WebGLShader {
  const s = gl.createShader(type)!;
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new RendererError(`shader: ${gl.getShaderInfoLog(s)}`);
  return s;
}

export class Program {
  readonly program: WebGLProgram;
  private locations = new Map<string, WebGLUniformLocation | null>();
  constructor(private gl: WebGL2RenderingContext, vertex: string, fragment: string) {
    const p = gl.createProgram()!;
    gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vertex));
    gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fragment));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new RendererError(`program: ${gl.getProgramInfoLog(p)}`);
    this.program = p;
  }
  loc(name: string) {
    if (!this.locations.has(name)) this.locations.set(name, this.gl.getUniformLocation(this.program, name));
    return this.locations.get(name)!;
  }
  dispose() {
    for (const s of this.gl.getAttachedShaders(this.program) ?? []) this.gl.deleteShader(s);
    this.gl.deleteProgram(this.program);
  }
}

interface Targets {
  w: number;
  h: number;
  fb: WebGLFramebuffer;       // opaque frames: colour·w and normal·w, depth
  color: WebGLTexture;
  normal: WebGLTexture;
  depth: WebGLTexture;
  // Translucent frames (float targets only): the opacity's sum, a second
  // depth (layers alternate: one is drawn while the other is read), the
  // layers' composite, and framebuffers for each kind of pass.
  alpha: WebGLTexture | null;
  depth2: WebGLTexture | null;
  composite: WebGLTexture | null;
  fbDepth: WebGLFramebuffer | null;
  fbLayer: WebGLFramebuffer | null;
  fbComposite: WebGLFramebuffer | null;
}

export class SplatRenderer {
  readonly gl: WebGL2RenderingContext;
  readonly floatBlend: boolean;
  readonly clipControl: boolean;
  private programs: Record<string, Program>;
  private targets: Targets | null = null;
  private pickTarget: { fb: WebGLFramebuffer; buffers: WebGLRenderbuffer[] } | null = null;
  private emptyVao: WebGLVertexArrayObject;

  private clipControlExt: ClipControl | null;
  private shared: boolean;

  // Throws RendererError naming what the browser lacks. `shared`: the canvas's
  // WebGL2 context is another renderer's too (three.js): the clip control is
  // set for each frame and put back after it.
  constructor(canvas: HTMLCanvasElement, options: { forbidFloatBlend?: boolean; shared?: boolean } = {}) {
    const gl = canvas.getContext("webgl2", { antialias: false, depth: false, preserveDrawingBuffer: true, alpha: false });
    if (!gl) throw new RendererError("this browser has no WebGL2, which the viewer needs");
    this.gl = gl;
    if (!gl.getExtension("EXT_color_buffer_float") && !gl.getExtension("EXT_color_buffer_half_float"))
      console.info("surfcast: no float render targets; drawing into 8-bit targets");
    const hasFloatTargets = !!gl.getExtension("EXT_color_buffer_float");
    this.floatBlend = hasFloatTargets && !options.forbidFloatBlend && !!gl.getExtension("EXT_float_blend");
    const clip = gl.getExtension("EXT_clip_control") as ClipControl | null;
    this.clipControl = !!clip;
    this.clipControlExt = clip;
    this.shared = !!options.shared;
    if (clip && !this.shared) clip.clipControlEXT(clip.LOWER_LEFT_EXT, clip.ZERO_TO_ONE_EXT);
    const unsigned8 = !this.floatBlend;  // RGBA8 accumulation targets (ensureTargets)
    const program = (name: keyof typeof shaderSources) => new Program(gl, ...shaderSources[name]);
    this.programs = {
      visibility: program("visibility"),
      accumulate: program(unsigned8 ? "accumulate8" : "accumulate"),
      circles: program("circles"),
      points: program("points"),
      resolve: program(unsigned8 ? "resolve8" : "resolve"),
      resolveOver: program(unsigned8 ? "resolveOver8" : "resolveOver"),
      pick: program("pick"),
    };
    if (this.floatBlend) {
      this.programs.peel = program("peel");
      this.programs.layer = program("layer");
      this.programs.resolveLayer = program("resolveLayer");
      this.programs.composite = program("composite");
    }
    this.emptyVao = gl.createVertexArray()!;
  }

  // The mode actually drawn: per-pixel normalization needs float blending.
  effectiveMode(mode: RenderMode, hasWeights: boolean): RenderMode {
    if (this.floatBlend || mode === "points" || mode === "circles") return mode;
    return hasWeights ? "ewa-surfel" : "circles";
  }

  upload(surfels: ArrayBuffer): DrawnNode {
    const gl = this.gl;
    const count = surfels.byteLength / 32;
    const rows = Math.max(1, Math.ceil(count / kSurfelsPerRow));
    const data = new Uint32Array(rows * kSurfelsPerRow * 8);
    data.set(new Uint32Array(surfels));
    const texture = gl.createTexture()!;
    gl.bindTexture(gl.TEXTURE_2D, texture);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32UI, 2 * kSurfelsPerRow, rows);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 2 * kSurfelsPerRow, rows, gl.RGBA_INTEGER, gl.UNSIGNED_INT, data);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    return { texture, count };
  }

  release(node: DrawnNode) {
    this.gl.deleteTexture(node.texture);
  }

  // Frees every GL object the renderer made (the nodes' textures are the streamer's).
  dispose() {
    const gl = this.gl;
    this.deleteTargets();
    if (this.pickTarget) {
      gl.deleteFramebuffer(this.pickTarget.fb);
      for (const rb of this.pickTarget.buffers) gl.deleteRenderbuffer(rb);
      this.pickTarget = null;
    }
    for (const p of Object.values(this.programs)) p.dispose();
    gl.deleteVertexArray(this.emptyVao);
  }

  private deleteTargets() {
    const gl = this.gl, t = this.targets;
    if (!t) return;
    for (const fb of [t.fb, t.fbDepth, t.fbLayer, t.fbComposite]) if (fb) gl.deleteFramebuffer(fb);
    for (const x of [t.color, t.normal, t.depth, t.alpha, t.depth2, t.composite]) if (x) gl.deleteTexture(x);
    this.targets = null;
  }

  private ensureTargets(w: number, h: number): Targets {
    const gl = this.gl;
    if (this.targets && this.targets.w === w && this.targets.h === h) return this.targets;
    this.deleteTargets();
    const texture = (internal: number) => {
      const t = gl.createTexture()!;
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texStorage2D(gl.TEXTURE_2D, 1, internal, w, h);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      return t;
    };
    const framebuffer = (colors: WebGLTexture[], depth: WebGLTexture | null) => {
      const fb = gl.createFramebuffer()!;
      gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
      colors.forEach((c, i) => gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, gl.TEXTURE_2D, c, 0));
      if (depth) gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, depth, 0);
      gl.drawBuffers(colors.length ? colors.map((_, i) => gl.COLOR_ATTACHMENT0 + i) : [gl.NONE]);
      const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
      if (status !== gl.FRAMEBUFFER_COMPLETE) throw new RendererError(`the render targets are incomplete (0x${status.toString(16)})`);
      return fb;
    };
    const accum = this.floatBlend ? gl.RGBA32F : gl.RGBA8;
    const color = texture(accum), normal = texture(accum), depth = texture(gl.DEPTH_COMPONENT32F);
    const t: Targets = { w, h, fb: framebuffer([color, normal], depth), color, normal, depth, alpha: null, depth2: null,
                         composite: null, fbDepth: null, fbLayer: null, fbComposite: null };
    if (this.floatBlend) {
      t.alpha = texture(gl.R32F);
      t.depth2 = texture(gl.DEPTH_COMPONENT32F);
      t.composite = texture(gl.RGBA32F);
      t.fbDepth = framebuffer([], depth);
      t.fbLayer = framebuffer([color, normal, t.alpha], depth);
      t.fbComposite = framebuffer([t.composite], null);
    }
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    this.targets = t;
    return t;
  }

  // Whether frames with these settings peel layers (float targets only).
  translucentFrame(s: RenderSettings, mode: RenderMode): boolean {
    return this.floatBlend && (s.translucent || s.opacity < 1) && mode !== "points" && mode !== "circles";
  }

  private setFrame(p: Program, view: FrameView, s: RenderSettings, mode: RenderMode, w: number, h: number) {
    const gl = this.gl;
    gl.useProgram(p.program);
    gl.uniform4f(p.loc("frame.view0"), view.rows[0], view.rows[1], view.rows[2], view.rows[3]);
    gl.uniform4f(p.loc("frame.view1"), view.rows[4], view.rows[5], view.rows[6], view.rows[7]);
    gl.uniform4f(p.loc("frame.view2"), view.rows[8], view.rows[9], view.rows[10], view.rows[11]);
    gl.uniform4f(p.loc("frame.viewport"), view.eta, w, h, view.near);
    gl.uniform4f(p.loc("frame.kernel"), s.kernelScale, s.cutoff, s.zt, mode === "ewa-noprefilter" ? 0 : s.lowpassVariance);
    const o = view.origin, lo = s.clip?.min ?? o, hi = s.clip?.max ?? o;
    gl.uniform4f(p.loc("frame.clipMin"), lo[0] - o[0], lo[1] - o[1], lo[2] - o[2], s.edgeTau);
    gl.uniform4f(p.loc("frame.clipMax"), hi[0] - o[0], hi[1] - o[1], hi[2] - o[2], Math.min(Math.max(s.opacity, 0), 1));
    const unorm8 = (v: number) => Math.round(Math.min(Math.max(v, 0), 1) * 255);
    gl.uniform1ui(p.loc("frame.background"), unorm8(s.background[0]) | unorm8(s.background[1]) << 8 | unorm8(s.background[2]) << 16);
    const modes: Record<RenderMode, number> = { points: S.kModePoints, circles: S.kModeCircles,
      "ewa-noprefilter": S.kModeEwaNoPrefilter, "ewa-surfel": S.kModeEwaSurfel, "ewa-pixel": S.kModeEwaPixel };
    gl.uniform1ui(p.loc("frame.mode"), modes[mode]);
    const edgeAA = s.edgeAA && this.floatBlend;  // coverage sums past 1 need float targets
    gl.uniform1ui(p.loc("frame.flags"), (s.backfaceCull ? S.kFlagBackfaceCull : 0) | (edgeAA ? S.kFlagEdgeAA : 0) |
      (s.shading !== "unlit" ? S.kFlagLit : 0) | (s.shading === "phong" ? S.kFlagSpecular : 0) | (s.clip ? S.kFlagClip : 0));
    gl.uniform1i(p.loc("scClipControl"), this.clipControl ? 1 : 0);
    gl.uniform1i(p.loc("scSurfels"), 2);
  }

  // In a shared context: depth in [0, 1] from clip z for this renderer's
  // passes, and the other renderer's setting back after them.
  private withClipControl<R>(draw: () => R): R {
    const ext = this.clipControlExt;
    if (!this.shared || !ext) return draw();
    const gl = this.gl;
    const origin = gl.getParameter(ext.CLIP_ORIGIN_EXT), depth = gl.getParameter(ext.CLIP_DEPTH_MODE_EXT);
    ext.clipControlEXT(ext.LOWER_LEFT_EXT, ext.ZERO_TO_ONE_EXT);
    try {
      return draw();
    } finally {
      ext.clipControlEXT(origin, depth);
    }
  }

  // Draws the nodes into the canvas (its drawing-buffer size), over and
  // against a scene where `composite` is given (then opaque: translucent
  // frames are not peeled).
  render(nodes: DrawnNode[], view: FrameView, settings: RenderSettings, hasWeights: boolean, composite?: SceneComposite) {
    this.withClipControl(() => this.draw(nodes, view, settings, hasWeights, composite));
  }

  private draw(nodes: DrawnNode[], view: FrameView, settings: RenderSettings, hasWeights: boolean, composite?: SceneComposite) {
    const gl = this.gl;
    const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    const t = this.ensureTargets(w, h);
    const mode = this.effectiveMode(settings.mode, hasWeights);
    gl.bindFramebuffer(gl.FRAMEBUFFER, t.fb);
    gl.drawBuffers([gl.COLOR_ATTACHMENT0, gl.COLOR_ATTACHMENT1]);
    gl.viewport(0, 0, w, h);
    gl.disable(gl.CULL_FACE);
    gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 0]);
    gl.clearBufferfv(gl.COLOR, 1, [0, 0, 0, 0]);
    gl.clearDepth(0);  // reversed Z: 0 is infinitely far
    gl.depthMask(true);
    gl.clear(gl.DEPTH_BUFFER_BIT);
    if (composite) {
      gl.drawBuffers([gl.NONE, gl.NONE]);
      composite.depth(gl, view.near);
      gl.drawBuffers([gl.COLOR_ATTACHMENT0, gl.COLOR_ATTACHMENT1]);
    }
    gl.enable(gl.DEPTH_TEST);
    const drawAll = (primitive: number, verticesPerSurfel: number) => {
      gl.bindVertexArray(this.emptyVao);
      gl.activeTexture(gl.TEXTURE2);
      for (const n of nodes) {
        gl.bindTexture(gl.TEXTURE_2D, n.texture);
        gl.drawArrays(primitive, 0, verticesPerSurfel * n.count);
      }
    };
    if (!composite && this.translucentFrame(settings, mode)) {
      this.renderLayers(t, drawAll, view, settings, mode, w, h);
      return;
    }
    if (mode === "points" || mode === "circles") {
      const p = this.programs[mode];
      this.setFrame(p, view, settings, mode, w, h);
      gl.disable(gl.BLEND);
      gl.depthFunc(gl.GREATER);
      gl.depthMask(true);
      drawAll(mode === "points" ? gl.POINTS : gl.TRIANGLES, mode === "points" ? 1 : 6);
    } else {
      const vis = this.programs.visibility;
      this.setFrame(vis, view, settings, mode, w, h);
      gl.disable(gl.BLEND);
      gl.colorMask(false, false, false, false);
      gl.depthFunc(gl.GREATER);
      gl.depthMask(true);
      drawAll(gl.TRIANGLES, 6);
      const acc = this.programs.accumulate;
      this.setFrame(acc, view, settings, mode, w, h);
      gl.colorMask(true, true, true, true);
      gl.depthMask(false);
      gl.depthFunc(gl.GEQUAL);
      gl.enable(gl.BLEND);
      gl.blendEquation(gl.FUNC_ADD);
      gl.blendFunc(gl.ONE, gl.ONE);
      drawAll(gl.TRIANGLES, 6);
      gl.disable(gl.BLEND);
    }
    gl.depthMask(true);
    gl.disable(gl.DEPTH_TEST);
    gl.bindVertexArray(this.emptyVao);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, w, h);
    if (composite) {
      composite.background(gl);
      // The resolve over a black background is the splats premultiplied by their coverage.
      gl.enable(gl.BLEND);
      gl.blendEquation(gl.FUNC_ADD);
      gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
      settings = { ...settings, background: [0, 0, 0] };
    }
    gl.bindVertexArray(this.emptyVao);
    const r = composite ? this.programs.resolveOver : this.programs.resolve;
    this.setFrame(r, view, settings, mode, w, h);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, t.color);
    gl.uniform1i(r.loc("colorWeight"), 0);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, t.normal);
    gl.uniform1i(r.loc("normalWeight"), 1);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.disable(gl.BLEND);
    gl.bindVertexArray(null);
  }

  // The splat under drawing-buffer pixel (x, y) (from the top left) of the
  // nodes as render() draws them: the nearest by its own depth, as its
  // node's place in `nodes` and its surfel's index in the node; null where
  // no splat covers the pixel. Only that pixel is rasterized: the viewport
  // moves it onto a 1x1 target, whose integer id is read back.
  pick(nodes: DrawnNode[], view: FrameView, settings: RenderSettings, x: number, y: number): { node: number; surfel: number } | null {
    return this.withClipControl(() => this.pickNow(nodes, view, settings, x, y));
  }

  private pickNow(nodes: DrawnNode[], view: FrameView, settings: RenderSettings, x: number, y: number) {
    const gl = this.gl;
    const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    if (!(x >= 0 && x < w && y >= 0 && y < h)) return null;
    if (!this.pickTarget) {
      const fb = gl.createFramebuffer()!, buffers: WebGLRenderbuffer[] = [];
      gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
      for (const [attachment, format] of [[gl.COLOR_ATTACHMENT0, gl.RG32UI], [gl.DEPTH_ATTACHMENT, gl.DEPTH_COMPONENT32F]]) {
        const rb = gl.createRenderbuffer()!;
        gl.bindRenderbuffer(gl.RENDERBUFFER, rb);
        gl.renderbufferStorage(gl.RENDERBUFFER, format, 1, 1);
        gl.framebufferRenderbuffer(gl.FRAMEBUFFER, attachment, gl.RENDERBUFFER, rb);
        buffers.push(rb);
      }
      const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
      if (status !== gl.FRAMEBUFFER_COMPLETE) {
        gl.bindFramebuffer(gl.FRAMEBUFFER, null);
        gl.deleteFramebuffer(fb);
        for (const rb of buffers) gl.deleteRenderbuffer(rb);
        throw new RendererError(`the picking target is incomplete (0x${status.toString(16)})`);
      }
      this.pickTarget = { fb, buffers };
    }
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.pickTarget.fb);
    gl.drawBuffers([gl.COLOR_ATTACHMENT0]);
    gl.viewport(-Math.floor(x), -(h - 1 - Math.floor(y)), w, h);
    gl.colorMask(true, true, true, true);
    gl.clearBufferuiv(gl.COLOR, 0, [0, 0, 0, 0]);
    gl.clearDepth(0);  // reversed Z: 0 is infinitely far
    gl.depthMask(true);
    gl.clear(gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.GREATER);
    gl.disable(gl.BLEND);
    gl.disable(gl.CULL_FACE);
    const p = this.programs.pick;
    this.setFrame(p, view, settings, settings.mode === "ewa-noprefilter" ? "ewa-noprefilter" : "ewa-pixel", w, h);
    gl.bindVertexArray(this.emptyVao);
    gl.activeTexture(gl.TEXTURE2);
    nodes.forEach((n, k) => {
      gl.uniform1ui(p.loc("scPickNode"), k);
      gl.bindTexture(gl.TEXTURE_2D, n.texture);
      gl.drawArrays(gl.TRIANGLES, 0, 6 * n.count);
    });
    const id = new Uint32Array(4);
    gl.readPixels(0, 0, 1, 1, gl.RGBA_INTEGER, gl.UNSIGNED_INT, id);
    gl.disable(gl.DEPTH_TEST);
    gl.bindVertexArray(null);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, w, h);
    return id[0] ? { node: id[0] - 1, surfel: id[1] } : null;
  }

  // Depth peeling (docs/RENDERER.md, "Transparency"; splat_renderer.cpp's
  // translucent path): for each layer k, a visibility pass (k > 0: behind
  // layer k-1's pushed-back surface) into one depth while the other holds
  // layer k-1's, an accumulation pass within z_t of it (the last layer takes
  // every fragment behind the others), and the layer's resolve blended under
  // the layers in front; then the composite over the background.
  private renderLayers(t: Targets, drawAll: (primitive: number, vertices: number) => void, view: FrameView,
                       s: RenderSettings, mode: RenderMode, w: number, h: number) {
    const gl = this.gl;
    const p = this.programs;
    const layers = Math.min(Math.max(Math.round(s.layers), 1), kMaxLayers);
    const depths = [t.depth, t.depth2!];
    const bindTexture = (unit: number, texture: WebGLTexture, program: Program, name: string) => {
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, texture);
      gl.uniform1i(program.loc(name), unit);
    };
    const fullscreen = () => {
      gl.bindVertexArray(this.emptyVao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    };
    for (let k = 0; k < layers; ++k) {
      const current = depths[k % 2], previous = depths[(k + 1) % 2];
      for (const fb of [t.fbDepth!, t.fbLayer!]) {
        gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
        gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, current, 0);
      }
      gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbDepth);
      gl.viewport(0, 0, w, h);
      gl.clearDepth(0);
      gl.clear(gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.GREATER);
      gl.depthMask(true);
      gl.disable(gl.BLEND);
      const vis = k === 0 ? p.visibility : p.peel;
      this.setFrame(vis, view, s, mode, w, h);
      if (k > 0) bindTexture(3, previous, vis, "previousDepth");
      drawAll(gl.TRIANGLES, 6);

      gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbLayer);
      for (let i = 0; i < 3; ++i) gl.clearBufferfv(gl.COLOR, i, [0, 0, 0, 0]);
      gl.depthMask(false);
      if (k + 1 === layers) gl.disable(gl.DEPTH_TEST);  // the last layer: every fragment behind the others
      else gl.depthFunc(gl.GEQUAL);
      gl.enable(gl.BLEND);
      gl.blendEquation(gl.FUNC_ADD);
      gl.blendFunc(gl.ONE, gl.ONE);
      this.setFrame(p.layer, view, s, mode, w, h);
      gl.uniform1ui(p.layer.loc("frame.layer"), k);
      bindTexture(3, previous, p.layer, "previousDepth");
      drawAll(gl.TRIANGLES, 6);
      gl.disable(gl.DEPTH_TEST);
      gl.depthMask(true);

      gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbComposite);
      if (k === 0) gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 0]);
      gl.blendFuncSeparate(gl.ONE_MINUS_DST_ALPHA, gl.ONE, gl.ONE_MINUS_DST_ALPHA, gl.ONE);  // under: dst += (1 - dst.a) src
      this.setFrame(p.resolveLayer, view, s, mode, w, h);
      bindTexture(0, t.color, p.resolveLayer, "colorWeight");
      bindTexture(1, t.normal, p.resolveLayer, "normalWeight");
      bindTexture(4, t.alpha!, p.resolveLayer, "alphaWeight");
      fullscreen();
      gl.disable(gl.BLEND);
      // Unbind the sampled depth before a later pass draws into it.
      gl.activeTexture(gl.TEXTURE3);
      gl.bindTexture(gl.TEXTURE_2D, null);
    }
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, w, h);
    this.setFrame(p.composite, view, s, mode, w, h);
    bindTexture(0, t.composite!, p.composite, "composite");
    fullscreen();
    gl.bindVertexArray(null);
  }
}
