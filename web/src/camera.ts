// Cameras in the set's world coordinates (double precision, as JavaScript
// numbers are), with the same conventions as common/camera.h: camera space x
// right, y up, z forward; a camera-space point o projects to
//   x = W/2 + eta o.x / o.z,  y = H/2 - eta o.y / o.z,  eta = H / (2 tan(fov/2)).

import defaults from "../../common/render_defaults.json";
import type { Vec3 } from "./format.js";

// frameBox's share of the image's half extents the box's corners may reach
// (common/render_defaults.json, which the C++ frameBox reads too).
const kFrameMargin = defaults.renderer.frame_margin;

export interface Camera {
  eye: Vec3;
  target: Vec3;
  up: Vec3;
  fov: number; // vertical, degrees
}

export const sub = (a: Vec3, b: Vec3): Vec3 => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const add = (a: Vec3, b: Vec3): Vec3 => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const scale = (a: Vec3, s: number): Vec3 => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a: Vec3, b: Vec3) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a: Vec3, b: Vec3): Vec3 => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const length = (a: Vec3) => Math.sqrt(dot(a, a));
export function normalize(a: Vec3): Vec3 {
  const l = length(a);
  return l > 0 && Number.isFinite(l) ? scale(a, 1 / l) : [0, 0, 0];
}

// Why a camera cannot be used, or null (common/camera.cpp's checkCamera).
export function cameraProblem(c: Camera): string | null {
  const all = [...c.eye, ...c.target, ...c.up, c.fov];
  if (!all.every(Number.isFinite)) return "camera has a non-finite value";
  if (!(c.fov > 0 && c.fov < 180)) return `camera field of view ${c.fov} is outside (0, 180) degrees`;
  const forward = sub(c.target, c.eye);
  if (!(length(forward) > 0)) return "camera eye and target coincide";
  if (!(length(cross(normalize(forward), normalize(c.up))) > 1e-9))
    return "camera up vector is parallel to the view direction (or zero)";
  return null;
}

// "ex,ey,ez,tx,ty,tz,ux,uy,uz,fov", as surfcast-view --camera takes it.
export function parseCamera(text: string): Camera {
  const v = text.split(",").map((s) => Number(s.trim()));
  if (v.length !== 10 || v.some((x) => !Number.isFinite(x)))
    throw new Error(`camera "${text}": expected ten numbers ex,ey,ez,tx,ty,tz,ux,uy,uz,fov`);
  const c: Camera = { eye: [v[0], v[1], v[2]], target: [v[3], v[4], v[5]], up: [v[6], v[7], v[8]], fov: v[9] };
  const problem = cameraProblem(c);
  if (problem) throw new Error(`camera "${text}": ${problem}`);
  return c;
}

export function formatCamera(c: Camera): string {
  const r = (x: number) => String(Number(x.toPrecision(9)));
  return [...c.eye, ...c.target, ...c.up, c.fov].map(r).join(",");
}

export interface CameraAxes {
  right: Vec3;
  up: Vec3;
  forward: Vec3;
}
export function cameraAxes(c: Camera): CameraAxes {
  const forward = normalize(sub(c.target, c.eye));
  const right = normalize(cross(forward, c.up));
  return { right, up: cross(right, forward), forward };
}

export function viewportScale(c: Camera, height: number): number {
  return height / (2 * Math.tan((0.5 * c.fov * Math.PI) / 180));
}

// Where frameBox looks from: (±0.35, ±1, ±0.55), the first its usual one.
export function frameDirection(i: number): Vec3 {
  return normalize([i & 1 ? -0.35 : 0.35, i & 2 ? 1 : -1, i & 4 ? -0.55 : 0.55]);
}

// A camera that frames the box at `aspect` (width / height), as surfcast-view
// frames a set without --camera.
export function frameBox(min: Vec3, max: Vec3, aspect: number, fov = 45, direction = 0): Camera {
  const centre = scale(add(min, max), 0.5);
  const d = frameDirection(direction);
  const a = cameraAxes({ eye: add(centre, d), target: centre, up: [0, 0, 1], fov });
  // The nearest eye along d, from a target moved across the view, from which
  // every corner projects within the margin of the image's half extents, the
  // box centred (common/camera.cpp derives it).
  const tanY = kFrameMargin * Math.tan((0.5 * fov * Math.PI) / 180), tanX = tanY * aspect;
  const p = [0, 1, 2, 3, 4, 5, 6, 7].map((i) => sub([i & 1 ? max[0] : min[0], i & 2 ? max[1] : min[1], i & 4 ? max[2] : min[2]], centre));
  let distance = 1e-9 * Math.max(1, length(sub(max, min)), length(centre));  // a box of one point too
  for (const pi of p)
    for (const pj of p)
      distance = Math.max(distance, (dot(sub(pi, pj), a.right) / tanX + dot(add(pi, pj), d)) / 2,
                          (dot(sub(pi, pj), a.up) / tanY + dot(add(pi, pj), d)) / 2);
  const middle = (axis: Vec3, tan: number) => {
    let lo = -Infinity, hi = Infinity;
    for (const q of p) {
      const z = distance - dot(q, d);
      lo = Math.max(lo, dot(q, axis) - tan * z);
      hi = Math.min(hi, dot(q, axis) + tan * z);
    }
    return 0.5 * (lo + hi);
  };
  const target = add(centre, add(scale(a.right, middle(a.right, tanX)), scale(a.up, middle(a.up, tanY))));
  return { eye: add(target, scale(d, distance)), target, up: [0, 0, 1], fov };
}

// World -> camera rows (r, -r.(eye - origin)) relative to `origin`, for the
// GPU's float positions: 12 floats, row-major 3 x 4.
export function viewRows(c: Camera, origin: Vec3): Float32Array {
  const a = cameraAxes(c);
  const eye = sub(c.eye, origin);
  const rows = new Float32Array(12);
  [a.right, a.up, a.forward].forEach((axis, r) => {
    rows.set(axis, 4 * r);
    rows[4 * r + 3] = -dot(axis, eye);
  });
  return rows;
}
