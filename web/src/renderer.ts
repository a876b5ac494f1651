// Object-space EWA splatting on WebGL2 (Ren et al. 2002; docs/RENDERER.md):
// a visibility pass of elliptical quads pushed back by z_t writes depth, an
// accumulation pass adds colour·w, w, normal·w and the unscaled kernel into
// two float targets where the splat is within z_t of the nearest surface, and
// a resolve normalizes per pixel, shades and antialiases edges (Zwicker 2001
// §7). Points and circles draw opaque, nearest wins. Each node is one vertex
// buffer of 32-byte surfels (the GpuSurfel layout), drawn as instanced quads.
//
// Float blending (EXT_float_blend) is what per-pixel normalization needs.
// Without it the accumulation targets are 8-bit, where only the 2002 paper's
// per-surfel weights work (ewa-surfel, no division): that is what the
// renderer falls back to, and to circles for sets without weights.

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
}

// The defaults of client/render/render_settings.h.
export const kDefaultLowpassVariance = 0.1;
export const kDefaultEdgeTau = 4;
export const kDefaultZt = 0.5;
export const kMaxFilterPixels = 64;
export const kNearFraction = 1e-4;

export interface FrameView {
  rows: Float32Array; // world (relative to the render origin) -> camera, 3 x 4 row-major
  eta: number;
  near: number;
}

export interface DrawnNode {
  buffer: WebGLBuffer;
  vao: WebGLVertexArrayObject;
  count: number;
}

export class RendererError extends Error {}

function compile(gl: WebGL2RenderingContext, type: number, source: string): WebGLShader {
  const s = gl.createShader(type)!;
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new RendererError(`shader: ${gl.getShaderInfoLog(s)}`);
  return s;
}

class Program {
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
}

export class SplatRenderer {
  readonly gl: WebGL2RenderingContext;
  readonly floatBlend: boolean;
  readonly clipControl: boolean;
  private programs: Record<string, Program>;
  private targets: { fb: WebGLFramebuffer; color: WebGLTexture; normal: WebGLTexture; depth: WebGLTexture; w: number; h: number } | null = null;
  private emptyVao: WebGLVertexArrayObject;

  // Throws RendererError naming what the browser lacks.
  constructor(canvas: HTMLCanvasElement, options: { forbidFloatBlend?: boolean } = {}) {
    const gl = canvas.getContext("webgl2", { antialias: false, depth: false, preserveDrawingBuffer: true, alpha: false });
    if (!gl) throw new RendererError("this browser has no WebGL2, which the viewer needs");
    this.gl = gl;
    if (!gl.getExtension("EXT_color_buffer_float") && !gl.getExtension("EXT_color_buffer_half_float"))
      console.info("surfcast: no float render targets; drawing into 8-bit targets");
    const hasFloatTargets = !!gl.getExtension("EXT_color_buffer_float");
    this.floatBlend = hasFloatTargets && !options.forbidFloatBlend && !!gl.getExtension("EXT_float_blend");
    const clip = gl.getExtension("EXT_clip_control");
    this.clipControl = !!clip;
    if (clip) clip.clipControlEXT(clip.LOWER_LEFT_EXT, clip.ZERO_TO_ONE_EXT);
    this.programs = {
      visibility: new Program(gl, S.splatVertex(S.kPassVisibility), S.visibilityFragment),
      accumulate: new Program(gl, S.splatVertex(S.kPassAccumulate), S.accumulateFragment),
      circles: new Program(gl, S.splatVertex(S.kPassCircles), S.opaqueFragment(true)),
      points: new Program(gl, S.splatVertex(S.kPassPoints), S.opaqueFragment(false)),
      resolve: new Program(gl, S.resolveVertex, S.resolveFragment),
    };
    this.emptyVao = gl.createVertexArray()!;
  }

  // The mode actually drawn: per-pixel normalization needs float blending.
  effectiveMode(mode: RenderMode, hasWeights: boolean): RenderMode {
    if (this.floatBlend || mode === "points" || mode === "circles") return mode;
    return hasWeights ? "ewa-surfel" : "circles";
  }

  upload(surfels: ArrayBuffer): DrawnNode {
    const gl = this.gl;
    const buffer = gl.createBuffer()!;
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, surfels, gl.STATIC_DRAW);
    const vao = gl.createVertexArray()!;
    gl.bindVertexArray(vao);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 4, gl.FLOAT, false, 32, 0);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribIPointer(1, 1, gl.UNSIGNED_INT, 32, 16);
    gl.enableVertexAttribArray(2);
    gl.vertexAttribPointer(2, 4, gl.UNSIGNED_BYTE, true, 32, 20);
    gl.enableVertexAttribArray(3);
    gl.vertexAttribPointer(3, 1, gl.FLOAT, false, 32, 24);
    gl.enableVertexAttribArray(4);
    gl.vertexAttribIPointer(4, 1, gl.UNSIGNED_INT, 32, 28);
    for (let i = 0; i < 5; ++i) gl.vertexAttribDivisor(i, 1);
    gl.bindVertexArray(null);
    return { buffer, vao, count: surfels.byteLength / 32 };
  }

  release(node: DrawnNode) {
    this.gl.deleteVertexArray(node.vao);
    this.gl.deleteBuffer(node.buffer);
  }

  private ensureTargets(w: number, h: number) {
    const gl = this.gl;
    if (this.targets && this.targets.w === w && this.targets.h === h) return this.targets;
    if (this.targets) {
      gl.deleteFramebuffer(this.targets.fb);
      for (const t of [this.targets.color, this.targets.normal, this.targets.depth]) gl.deleteTexture(t);
    }
    const texture = (internal: number, format: number, type: number) => {
      const t = gl.createTexture()!;
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texStorage2D(gl.TEXTURE_2D, 1, internal, w, h);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      void format, type;
      return t;
    };
    const accum = this.floatBlend ? gl.RGBA32F : gl.RGBA8;
    const color = texture(accum, gl.RGBA, gl.FLOAT), normal = texture(accum, gl.RGBA, gl.FLOAT);
    const depth = texture(gl.DEPTH_COMPONENT32F, gl.DEPTH_COMPONENT, gl.FLOAT);
    const fb = gl.createFramebuffer()!;
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, color, 0);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT1, gl.TEXTURE_2D, normal, 0);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, depth, 0);
    const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
    if (status !== gl.FRAMEBUFFER_COMPLETE) throw new RendererError(`the accumulation targets are incomplete (0x${status.toString(16)})`);
    this.targets = { fb, color, normal, depth, w, h };
    return this.targets;
  }

  private setFrame(p: Program, view: FrameView, s: RenderSettings, mode: RenderMode, w: number, h: number) {
    const gl = this.gl;
    gl.useProgram(p.program);
    gl.uniform4f(p.loc("uView0"), view.rows[0], view.rows[1], view.rows[2], view.rows[3]);
    gl.uniform4f(p.loc("uView1"), view.rows[4], view.rows[5], view.rows[6], view.rows[7]);
    gl.uniform4f(p.loc("uView2"), view.rows[8], view.rows[9], view.rows[10], view.rows[11]);
    gl.uniform4f(p.loc("uViewport"), view.eta, w, h, view.near);
    gl.uniform4f(p.loc("uKernel"), s.kernelScale, s.cutoff, s.zt, mode === "ewa-noprefilter" ? 0 : s.lowpassVariance);
    gl.uniform4f(p.loc("uResolve"), s.background[0], s.background[1], s.background[2], s.edgeTau);
    const modes: Record<RenderMode, number> = { points: S.kModePoints, circles: S.kModeCircles,
      "ewa-noprefilter": S.kModeEwaNoPrefilter, "ewa-surfel": S.kModeEwaSurfel, "ewa-pixel": S.kModeEwaPixel };
    gl.uniform1ui(p.loc("uMode"), modes[mode]);
    gl.uniform1ui(p.loc("uShading"), s.shading === "unlit" ? S.kShadingUnlit : s.shading === "lambert" ? S.kShadingLambert : S.kShadingPhong);
    const edgeAA = s.edgeAA && this.floatBlend;  // coverage sums past 1 need float targets
    gl.uniform1ui(p.loc("uFlags"), (s.backfaceCull ? S.kFlagBackfaceCull : 0) | (edgeAA ? S.kFlagEdgeAA : 0));
    gl.uniform1f(p.loc("uMaxFilterPixels"), kMaxFilterPixels);
    gl.uniform1f(p.loc("uCircleScale"), s.kernelScale);
    gl.uniform1i(p.loc("uClipControl"), this.clipControl ? 1 : 0);
  }

  // Draws the nodes into the canvas (its drawing-buffer size).
  render(nodes: DrawnNode[], view: FrameView, settings: RenderSettings, hasWeights: boolean) {
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
    gl.clear(gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    const drawAll = (primitive: number, vertices: number) => {
      for (const n of nodes) {
        gl.bindVertexArray(n.vao);
        gl.drawArraysInstanced(primitive, 0, vertices, n.count);
      }
    };
    if (mode === "points" || mode === "circles") {
      const p = this.programs[mode];
      this.setFrame(p, view, settings, mode, w, h);
      gl.disable(gl.BLEND);
      gl.depthFunc(gl.GREATER);
      gl.depthMask(true);
      drawAll(mode === "points" ? gl.POINTS : gl.TRIANGLE_STRIP, mode === "points" ? 1 : 4);
    } else {
      const vis = this.programs.visibility;
      this.setFrame(vis, view, settings, mode, w, h);
      gl.disable(gl.BLEND);
      gl.colorMask(false, false, false, false);
      gl.depthFunc(gl.GREATER);
      gl.depthMask(true);
      drawAll(gl.TRIANGLE_STRIP, 4);
      const acc = this.programs.accumulate;
      this.setFrame(acc, view, settings, mode, w, h);
      gl.colorMask(true, true, true, true);
      gl.depthMask(false);
      gl.depthFunc(gl.GEQUAL);
      gl.enable(gl.BLEND);
      gl.blendEquation(gl.FUNC_ADD);
      gl.blendFunc(gl.ONE, gl.ONE);
      drawAll(gl.TRIANGLE_STRIP, 4);
      gl.disable(gl.BLEND);
    }
    gl.depthMask(true);
    gl.disable(gl.DEPTH_TEST);
    gl.bindVertexArray(this.emptyVao);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, w, h);
    const r = this.programs.resolve;
    this.setFrame(r, view, settings, mode, w, h);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, t.color);
    gl.uniform1i(r.loc("uColorWeight"), 0);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, t.normal);
    gl.uniform1i(r.loc("uNormalWeight"), 1);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindVertexArray(null);
  }
}
