// Surfcast in a three.js app (docs/WEB.md, "three.js"): SurfcastLayer draws
// a set into the app's WebGLRenderer, in the same WebGL2 context and canvas,
// with depth shared both ways: the app's scene is rendered into a target
// with a depth texture; its depth, turned into the splat renderer's
// reversed-Z depth, fills the visibility pass, so meshes in front hide the
// splats behind them; its colour is drawn first and the splats' resolve
// blends over it by coverage, so splats in front hide the meshes behind.
//
// Placement: three's world is the set's own coordinates less `origin` (the
// set's centre by default), so a georeferenced set keeps its precision, with
// no rotation (z up: give the camera up = (0, 0, 1)). The scene's camera is a
// PerspectiveCamera with a standard depth buffer (not logarithmic or reversed).

import * as THREE from "three";
import { Program } from "./renderer.js";
import { type PickResult, SurfcastViewer, type ViewerOptions } from "./viewer.js";

const kDepthImport = [`#version 300 es
precision highp float;
void main() {
  vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}`, `#version 300 es
precision highp float;
uniform highp sampler2D sceneDepth;
uniform vec3 planes; // the scene camera's near and far, the splat renderer's near
// The scene's window depth d (a standard perspective projection) as the view
// distance z, then as the splat renderer's reversed-Z depth near / z; where
// the scene has nothing (d = 1), 0: infinitely far.
void main() {
  float d = texelFetch(sceneDepth, ivec2(gl_FragCoord.xy), 0).r;
  float n = planes.x, f = planes.y;
  float z = 2.0 * n * f / (f + n - (2.0 * d - 1.0) * (f - n));
  gl_FragDepth = d >= 1.0 ? 0.0 : clamp(planes.z / z, 0.0, 1.0);
}`];
// The scene's colour as three would show it in the canvas: the target holds
// three's linear working colours, encoded here as sRGB where the renderer's
// output is (its tone mapping, if any, is not applied).
const kCopy = [kDepthImport[0], `#version 300 es
precision highp float;
uniform highp sampler2D sceneColor;
uniform bool srgb;
out vec4 color;
void main() {
  vec3 c = clamp(texelFetch(sceneColor, ivec2(gl_FragCoord.xy), 0).rgb, 0.0, 1.0);
  if (srgb) c = mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
  color = vec4(c, 1.0);
}`];

export interface LayerOptions extends Omit<ViewerOptions, "controls" | "loop" | "camera"> {
  origin?: [number, number, number]; // the set's point at three's world origin (default: its centre)
}

export class SurfcastLayer {
  // The set's point at three's world origin.
  readonly origin: [number, number, number];
  private target: THREE.WebGLRenderTarget;
  private depthProgram: Program;
  private copyProgram: Program;
  private vao: WebGLVertexArrayObject;

  // Opens the set at `setUrl` for drawing into `renderer`'s canvas. Throws as
  // SurfcastViewer.open does.
  static async open(renderer: THREE.WebGLRenderer, setUrl: string, options: LayerOptions = {}): Promise<SurfcastLayer> {
    const viewer = await SurfcastViewer.open(renderer.domElement, setUrl, { ...options, controls: false, loop: false });
    return new SurfcastLayer(renderer, viewer, options);
  }

  private constructor(private renderer: THREE.WebGLRenderer, readonly viewer: SurfcastViewer, options: LayerOptions) {
    const info = viewer.info;
    this.origin = options.origin ?? [0, 1, 2].map((a) => 0.5 * (info.boundsMin[a] + info.boundsMax[a])) as [number, number, number];
    const size = renderer.getDrawingBufferSize(new THREE.Vector2());
    // Float colour where the browser renders to it: three's linear colours
    // keep their precision until kCopy encodes them.
    const type = renderer.extensions.has("EXT_color_buffer_float") ? THREE.HalfFloatType : THREE.UnsignedByteType;
    this.target = new THREE.WebGLRenderTarget(size.x, size.y, { type,
      depthTexture: new THREE.DepthTexture(size.x, size.y, THREE.FloatType), depthBuffer: true });
    const gl = renderer.getContext() as WebGL2RenderingContext;
    this.depthProgram = new Program(gl, ...kDepthImport as [string, string]);
    this.copyProgram = new Program(gl, ...kCopy as [string, string]);
    this.vao = gl.createVertexArray()!;
    renderer.resetState();
  }

  // Renders `scene` from `camera` and the set with it, into the canvas.
  render(scene: THREE.Scene, camera: THREE.PerspectiveCamera) {
    const renderer = this.renderer;
    const size = renderer.getDrawingBufferSize(new THREE.Vector2());
    if (this.target.width !== size.x || this.target.height !== size.y) this.target.setSize(size.x, size.y);
    renderer.setRenderTarget(this.target);
    renderer.render(scene, camera);
    renderer.setRenderTarget(null);
    const texture = (t: THREE.Texture) => (renderer.properties.get(t) as { __webglTexture: WebGLTexture }).__webglTexture;
    const color = texture(this.target.texture), depth = texture(this.target.depthTexture!);
    camera.updateMatrixWorld();
    const eye = new THREE.Vector3().setFromMatrixPosition(camera.matrixWorld);
    const ahead = camera.getWorldDirection(new THREE.Vector3()).add(eye);
    const up = new THREE.Vector3(0, 1, 0).applyQuaternion(camera.getWorldQuaternion(new THREE.Quaternion()));
    const o = this.origin;
    const fullscreen = (gl: WebGL2RenderingContext, p: Program, name: string, t: WebGLTexture) => {
      gl.useProgram(p.program);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.uniform1i(p.loc(name), 0);
      gl.bindVertexArray(this.vao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    };
    renderer.resetState();  // GL's defaults (colour mask, scissor, stencil, ...), whatever three left set
    this.viewer.drawNow({
      eye: [eye.x + o[0], eye.y + o[1], eye.z + o[2]], target: [ahead.x + o[0], ahead.y + o[1], ahead.z + o[2]],
      up: [up.x, up.y, up.z], fov: camera.getEffectiveFOV(),
    }, {
      depth: (gl, near) => {
        gl.enable(gl.DEPTH_TEST);
        gl.depthFunc(gl.ALWAYS);
        gl.depthMask(true);
        gl.disable(gl.BLEND);
        gl.useProgram(this.depthProgram.program);
        gl.uniform3f(this.depthProgram.loc("planes"), camera.near, camera.far, near);
        fullscreen(gl, this.depthProgram, "sceneDepth", depth);
      },
      background: (gl) => {
        gl.disable(gl.DEPTH_TEST);
        gl.disable(gl.BLEND);
        gl.colorMask(true, true, true, true);
        gl.useProgram(this.copyProgram.program);
        gl.uniform1i(this.copyProgram.loc("srgb"), renderer.outputColorSpace === THREE.SRGBColorSpace ? 1 : 0);
        fullscreen(gl, this.copyProgram, "sceneColor", color);
      },
    });
    renderer.resetState();
  }

  // The surfel under canvas point (x, y) (CSS pixels) in the last frame
  // drawn, as SurfcastViewer.pick, with three's GL state kept. The splats are
  // picked alone: one behind a mesh can be picked.
  async pick(x: number, y: number): Promise<PickResult | null> {
    this.renderer.resetState();
    try {
      return await this.viewer.pick(x, y);
    } finally {
      this.renderer.resetState();
    }
  }

  dispose() {
    this.viewer.dispose();
    this.target.dispose();
    const gl = this.renderer.getContext() as WebGL2RenderingContext;
    for (const p of [this.depthProgram, this.copyProgram]) p.dispose();
    gl.deleteVertexArray(this.vao);
    this.renderer.resetState();
  }
}
