// The browser's level-of-detail selection (web/src/lod_selection.ts) under
// node, without a browser, on the cases the C++ selection runs
// (tests/conformance/, read by tests/lod_test.cpp too).

import { test } from "node:test";
import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { conformance, loadModule } from "./load_module.mjs";

const loadModules = () => loadModule('export * from "./src/lod_selection.ts"; export { parseCamera } from "./src/camera.ts";');

test("equal priorities refine smaller key first, as in the C++ client (conformance/lod_order.json)", async () => {
  const { LodSelector, emptyStats, parseCamera } = await loadModules();
  const c = JSON.parse(readFileSync(join(conformance, "lod_order.json"), "utf8"));
  const info = { rootMin: c.root_min, rootEdge: c.root_edge, levels: c.levels.length };
  const nodes = [];
  c.levels.forEach((l, level) => {
    for (let x = 0; x < 2 ** level; ++x)
      for (let y = 0; y < 2 ** level; ++y)
        for (let z = 0; z < 2 ** level; ++z)
          nodes.push({ key: `${level}-${x}-${y}-${z}`, level, x, y, z, childMask: level + 1 < c.levels.length ? 0xff : 0,
                       flags: 1 /* kFlagConeFull */, blockOffset: 0, blockSize: 0, blockCrc: 0, surfelCount: l.surfels,
                       spacing: l.spacing, coneAxis: [0, 0, 1], coneCos: -1, positionBits: 1, childPage: 0xffffffff });
  });
  const lod = new LodSelector(info, nodes);
  const stats = emptyStats();
  const drawn = lod.select(parseCamera(c.camera), c.width, c.height,
    { targetPixels: c.target_pixels, frustumCulling: false, backfaceCulling: false, splatBudget: c.splat_budget,
      memoryBudget: Infinity }, () => true, stats);
  const keys = drawn.map((s) => lod.nodes[s.index]).sort((a, b) => a.level - b.level || a.x - b.x || a.y - b.y || a.z - b.z)
    .map((n) => n.key);
  assert.deepEqual(keys, c.drawn);
  assert.ok(stats.budgetLimited > 0);
});
