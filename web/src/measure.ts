// Measurements on picked surfels, in the set's own coordinates and units:
// distance, height difference, polyline length, area and angle. The math is
// pure (measure.test.mjs checks it on hand-derived cases); Measurements
// draws each one as an SVG overlay over the canvas, projected again whenever
// the camera moves, until cleared.

import { type Camera, viewportScale, viewRows } from "./camera.js";
import type { Vec3 } from "./format.js";

export type Tool = "distance" | "height" | "polyline" | "area" | "angle";
export const kTools: Tool[] = ["distance", "height", "polyline", "area", "angle"];
// Points a tool takes before it is complete (polylines and areas take any
// number from 2 and 3: a double click or Enter ends them).
export const kToolPoints: Record<Tool, number> = { distance: 2, height: 2, polyline: Infinity, area: Infinity, angle: 3 };

const sub = (a: Vec3, b: Vec3): Vec3 => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const norm = (a: Vec3) => Math.hypot(a[0], a[1], a[2]);

export function distance(a: Vec3, b: Vec3): number {
  return norm(sub(b, a));
}
// |z_b - z_a|: z is up in every set (DESIGN.md).
export function heightDifference(a: Vec3, b: Vec3): number {
  return Math.abs(b[2] - a[2]);
}
export function polylineLength(points: Vec3[]): number {
  let sum = 0;
  for (let i = 1; i < points.length; ++i) sum += distance(points[i - 1], points[i]);
  return sum;
}
// The area of the closed polygon through the points: half the length of its
// vector area, sum(p_i x p_i+1) / 2, which is the area of a planar polygon
// in any orientation (and of a non-planar one's projection on its best plane).
export function polygonArea(points: Vec3[]): number {
  if (points.length < 3) return 0;
  const o = points[0];
  const s: Vec3 = [0, 0, 0];
  for (let i = 1; i + 1 < points.length; ++i) {
    const a = sub(points[i], o), b = sub(points[i + 1], o);
    s[0] += a[1] * b[2] - a[2] * b[1];
    s[1] += a[2] * b[0] - a[0] * b[2];
    s[2] += a[0] * b[1] - a[1] * b[0];
  }
  return 0.5 * norm(s);
}
// The angle at b between the rays to a and c, in degrees.
export function angleAt(a: Vec3, b: Vec3, c: Vec3): number {
  const u = sub(a, b), v = sub(c, b);
  const nu = norm(u), nv = norm(v);
  if (!(nu > 0 && nv > 0)) return 0;
  const cos = (u[0] * v[0] + u[1] * v[1] + u[2] * v[2]) / (nu * nv);
  return (Math.acos(Math.min(1, Math.max(-1, cos))) * 180) / Math.PI;
}

// A measurement's value and its label ("12.345" in the set's units, "m²"
// style suffixes left to the units' name).
export function measure(tool: Tool, points: Vec3[], unit = ""): { value: number; label: string } {
  const u = unit ? ` ${unit}` : "";
  switch (tool) {
    case "distance": {
      const v = points.length >= 2 ? distance(points[0], points[1]) : 0;
      return { value: v, label: `${v.toFixed(3)}${u}` };
    }
    case "height": {
      const v = points.length >= 2 ? heightDifference(points[0], points[1]) : 0;
      return { value: v, label: `Δz ${v.toFixed(3)}${u}` };
    }
    case "polyline": {
      const v = polylineLength(points);
      return { value: v, label: `${v.toFixed(3)}${u}` };
    }
    case "area": {
      const v = polygonArea(points);
      return { value: v, label: `${v.toFixed(3)}${u ? `${u}²` : " (units²)"}` };
    }
    case "angle": {
      const v = points.length >= 3 ? angleAt(points[0], points[1], points[2]) : 0;
      return { value: v, label: `${v.toFixed(2)}°` };
    }
  }
}

export interface Measurement {
  tool: Tool;
  points: Vec3[];
  done: boolean;
}

const kSvg = "http://www.w3.org/2000/svg";

// The measurements over a canvas: an SVG layer the size of the canvas,
// redrawn by draw(camera) (call it when the camera moves).
export class Measurements {
  readonly list: Measurement[] = [];
  private svg: SVGSVGElement;
  constructor(private canvas: HTMLCanvasElement, private origin: Vec3, readonly unit = "") {
    this.svg = document.createElementNS(kSvg, "svg");
    this.svg.id = "measurements";
    this.svg.setAttribute("aria-label", "measurements");
    canvas.insertAdjacentElement("afterend", this.svg);
  }

  // Adds a picked point to the measurement under way with `tool` (starting
  // one where none is), and returns it.
  add(tool: Tool, point: Vec3): Measurement {
    let m = this.list[this.list.length - 1];
    if (!m || m.done || m.tool !== tool) {
      m = { tool, points: [], done: false };
      this.list.push(m);
    }
    const last = m.points[m.points.length - 1];
    if (last && last.every((v, a) => v === point[a])) return m;  // the same surfel again (a double click's second click)
    m.points.push(point);
    if (m.points.length >= kToolPoints[tool]) m.done = true;
    return m;
  }
  // Ends the measurement under way (polylines and areas).
  finish() {
    const m = this.list[this.list.length - 1];
    if (m) m.done = true;
  }
  clear() {
    this.list.length = 0;
  }

  // Projects every measurement with `camera` and draws its lines and label.
  draw(camera: Camera) {
    const w = this.canvas.clientWidth, h = this.canvas.clientHeight;
    this.svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
    this.svg.replaceChildren();
    const rows = viewRows(camera, this.origin), eta = viewportScale(camera, h);
    const project = (p: Vec3): [number, number] | null => {
      const q: Vec3 = [p[0] - this.origin[0], p[1] - this.origin[1], p[2] - this.origin[2]];
      const c = [0, 1, 2].map((r) => rows[4 * r] * q[0] + rows[4 * r + 1] * q[1] + rows[4 * r + 2] * q[2] + rows[4 * r + 3]);
      return c[2] > 0 ? [w / 2 + (eta * c[0]) / c[2], h / 2 - (eta * c[1]) / c[2]] : null;
    };
    for (const m of this.list) {
      let shown = m.points;
      if (m.tool === "height" && m.points.length === 2) {
        // A vertical from the lower point up to the higher one's height.
        const [a, b] = m.points[0][2] <= m.points[1][2] ? m.points : [m.points[1], m.points[0]];
        shown = [a, [a[0], a[1], b[2]], b];
      }
      const screen = shown.map(project);
      if (screen.some((s) => s === null)) continue;  // behind the eye
      const xy = screen as [number, number][];
      const line = document.createElementNS(kSvg, m.tool === "area" && m.done ? "polygon" : "polyline");
      line.setAttribute("points", xy.map(([x, y]) => `${x.toFixed(1)},${y.toFixed(1)}`).join(" "));
      line.setAttribute("class", `measure ${m.tool}`);
      this.svg.append(line);
      for (const [x, y] of xy) {
        const dot = document.createElementNS(kSvg, "circle");
        dot.setAttribute("cx", x.toFixed(1));
        dot.setAttribute("cy", y.toFixed(1));
        dot.setAttribute("r", "3");
        this.svg.append(dot);
      }
      if (m.points.length < (m.tool === "angle" || m.tool === "area" ? 3 : 2)) continue;
      const at = m.tool === "angle" ? xy[1] : m.tool === "area" ? centroid(xy) : xy[xy.length - 1];
      const label = document.createElementNS(kSvg, "text");
      label.setAttribute("x", (at[0] + 6).toFixed(1));
      label.setAttribute("y", (at[1] - 6).toFixed(1));
      label.setAttribute("class", "label");
      label.textContent = measure(m.tool, m.points, this.unit).label;
      this.svg.append(label);
    }
  }
}

function centroid(points: [number, number][]): [number, number] {
  const n = points.length;
  return [points.reduce((s, p) => s + p[0], 0) / n, points.reduce((s, p) => s + p[1], 0) / n];
}
