// The browser's cameras (web/src/camera.ts) under node: frameBox fills the
// view as the C++ one does (tests/render_test.cpp, Camera.ParsesChecksAndFrames).

import { test } from "node:test";
import assert from "node:assert/strict";
import { loadModule } from "./load_module.mjs";

test("frameBox: every corner within 90 % of the half extents, two at it on opposite sides", async () => {
  const { frameBox, viewRows, viewportScale } = await loadModule("src/camera.ts");
  for (const [extent, aspect] of [[[30, 10, 15], 16 / 9], [[24, 24, 2], 16 / 9], [[24, 24, 2], 9 / 16]]) {
    const min = [1e6, 2e6, 10], max = min.map((v, a) => v + extent[a]);
    const origin = min.map((v, a) => 0.5 * (v + max[a]));
    const [w, h] = aspect > 1 ? [1600, 900] : [900, 1600];
    for (let direction = 0; direction < 8; ++direction) {
      const c = frameBox(min, max, aspect, 45, direction);
      const rows = viewRows(c, origin), eta = viewportScale(c, h);
      const lo = [Infinity, Infinity], hi = [-Infinity, -Infinity];
      for (let i = 0; i < 8; ++i) {
        const q = [i & 1 ? max[0] : min[0], i & 2 ? max[1] : min[1], i & 4 ? max[2] : min[2]].map((v, a) => v - origin[a]);
        const o = [0, 1, 2].map((r) => rows[4 * r] * q[0] + rows[4 * r + 1] * q[1] + rows[4 * r + 2] * q[2] + rows[4 * r + 3]);
        assert.ok(o[2] > 0);
        const x = eta * o[0] / o[2] / (w / 2), y = eta * o[1] / o[2] / (h / 2);
        assert.ok(Math.abs(x) <= 0.9 + 1e-4 && Math.abs(y) <= 0.9 + 1e-4, `direction ${direction}: corner ${i} at ${x}, ${y}`);
        [lo[0], hi[0], lo[1], hi[1]] = [Math.min(lo[0], x), Math.max(hi[0], x), Math.min(lo[1], y), Math.max(hi[1], y)];
      }
      const spans = (a) => Math.abs(hi[a] - 0.9) < 1e-4 && Math.abs(lo[a] + 0.9) < 1e-4;
      assert.ok(spans(0) || spans(1), `direction ${direction}: x ${lo[0]}..${hi[0]}, y ${lo[1]}..${hi[1]}`);
    }
  }
  // A box of one point, far from the origin: an eye apart from the target.
  const p = [4e7, -3e7, 100], c = frameBox(p, p, 1);
  assert.ok(c.eye.some((v, a) => v !== p[a]));
});
