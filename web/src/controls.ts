// Camera controls, mouse, keyboard and touch: orbit about the target (left
// drag, one finger), pan (right or shift drag, two fingers), zoom (wheel,
// pinch) and fly (W/A/S/D forward, left, back, right; Q/E down, up). Up stays
// the camera's up; the orbit keeps clear of the poles.

import { add, type Camera, cameraAxes, cross, dot, length, normalize, scale, sub } from "./camera.js";
import type { Vec3 } from "./format.js";

function rotate(v: Vec3, axis: Vec3, angle: number): Vec3 {
  // Rodrigues' rotation formula.
  const c = Math.cos(angle), s = Math.sin(angle);
  return add(add(scale(v, c), scale(cross(axis, v), s)), scale(axis, dot(axis, v) * (1 - c)));
}

export class Controls {
  private listening = new AbortController();
  constructor(private element: HTMLElement, private get: () => Camera, private set: (c: Camera) => void) {
    const signal = this.listening.signal;
    element.addEventListener("contextmenu", (e) => e.preventDefault(), { signal });
    element.addEventListener("pointerdown", (e) => this.down(e), { signal });
    element.addEventListener("pointermove", (e) => this.move(e), { signal });
    element.addEventListener("pointerup", (e) => this.up(e), { signal });
    element.addEventListener("pointercancel", (e) => this.up(e), { signal });
    element.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.zoom(Math.exp(e.deltaY * (e.deltaMode === 1 ? 0.05 : 0.001)));
    }, { passive: false, signal });
    window.addEventListener("keydown", (e) => this.key(e), { signal });
    element.style.touchAction = "none";
  }

  // Removes every listener.
  dispose() {
    this.listening.abort();
  }

  private pointers = new Map<number, { x: number; y: number; pan: boolean }>();
  private pinch = 0;

  private down(e: PointerEvent) {
    this.element.setPointerCapture(e.pointerId);
    this.pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey });
    this.pinch = this.spread();
  }
  private up(e: PointerEvent) {
    this.pointers.delete(e.pointerId);
    this.pinch = this.spread();
  }
  private spread(): number {
    const p = [...this.pointers.values()];
    return p.length === 2 ? Math.hypot(p[0].x - p[1].x, p[0].y - p[1].y) : 0;
  }
  private move(e: PointerEvent) {
    const p = this.pointers.get(e.pointerId);
    if (!p) return;
    const dx = e.clientX - p.x, dy = e.clientY - p.y;
    p.x = e.clientX;
    p.y = e.clientY;
    if (this.pointers.size === 2) {
      // Two fingers: pan by half the motion of each, zoom by the spread.
      this.pan(dx / 2, dy / 2);
      const s = this.spread();
      if (this.pinch > 0 && s > 0) this.zoom(this.pinch / s);
      this.pinch = s;
    } else if (p.pan) {
      this.pan(dx, dy);
    } else {
      this.orbit(dx, dy);
    }
  }

  orbit(dx: number, dy: number) {
    const c = this.get();
    const up = normalize(c.up);
    let offset = sub(c.eye, c.target);
    offset = rotate(offset, up, -dx * 0.005);
    const right = normalize(cross(offset, up));
    const turned = rotate(offset, right, dy * 0.005);
    // Keep clear of the poles, where up and the view direction meet.
    if (Math.abs(dot(normalize(turned), up)) < 0.995) offset = turned;
    this.set({ ...c, eye: add(c.target, offset) });
  }

  pan(dx: number, dy: number) {
    const c = this.get();
    const a = cameraAxes(c);
    const h = this.element.clientHeight || 1;
    const perPixel = (2 * length(sub(c.eye, c.target)) * Math.tan((0.5 * c.fov * Math.PI) / 180)) / h;
    const move = add(scale(a.right, -dx * perPixel), scale(a.up, dy * perPixel));
    this.set({ ...c, eye: add(c.eye, move), target: add(c.target, move) });
  }

  zoom(factor: number) {
    const c = this.get();
    const offset = sub(c.eye, c.target);
    if (!(length(offset) * factor > 1e-9)) return;
    this.set({ ...c, eye: add(c.target, scale(offset, factor)) });
  }

  private key(e: KeyboardEvent) {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    const c = this.get();
    const a = cameraAxes(c);
    const step = 0.05 * length(sub(c.eye, c.target));
    const moves: Record<string, Vec3> = {
      w: scale(a.forward, step), s: scale(a.forward, -step), a: scale(a.right, -step), d: scale(a.right, step),
      q: scale(a.up, -step), e: scale(a.up, step),
    };
    const m = moves[e.key.toLowerCase()];
    if (!m) return;
    this.set({ ...c, eye: add(c.eye, m), target: add(c.target, m) });
  }
}
