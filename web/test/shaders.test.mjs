// The browser's shaders as web/glsl_es.mjs generates them from client/shaders:
// every program compiles and links as GLSL ES 3.00 under glslang, Khronos's
// reference front end (the Vulkan build compiles the same files as GLSL 4.50),
// and nothing of Vulkan's syntax is left. Chromium draws them in browser_test.

import { test } from "node:test";
import assert from "node:assert/strict";
import { spawnSync } from "node:child_process";
import { mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { programs, sharedConstants } from "../glsl_es.mjs";

test("every generated program compiles and links as GLSL ES 3.00 (glslangValidator)", async (t) => {
  const dir = mkdtempSync(join(tmpdir(), "surfcast-glsl-es-"));
  try {
    for (const [name, [vertex, fragment]] of Object.entries(programs()))
      await t.test(name, () => {
        const glslang = (...args) => {
          const r = spawnSync("glslangValidator", args, { encoding: "utf8" });
          assert.equal(r.error, undefined, "glslangValidator runs (the client's build needs it too)");
          assert.equal(r.status, 0, r.stdout + r.stderr);
          return r.stdout;
        };
        const files = [[vertex, "vert"], [fragment, "frag"]].map(([source, stage]) => {
          assert.match(source, /^#version 300 es\n/);
          const file = join(dir, `${name}.${stage}`);
          writeFileSync(file, source);
          // Preprocessed, as the browser compiles it: Vulkan's branches gone.
          assert.doesNotMatch(glslang("-E", file), /gl_VertexIndex|push_constant|constant_id|binding =|noperspective|layout\(location = \d+\) (flat )?in /);
          return file;
        });
        glslang("-l", ...files);
      });
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

test("the constants shared_types.h defines reach the browser", () => {
  const c = sharedConstants();
  // The values the C++ client uses (client/shaders/shared_types.h, by hand here).
  assert.deepEqual([c.SC_MODE_POINTS, c.SC_MODE_CIRCLES, c.SC_MODE_EWA_NOPREFILTER, c.SC_MODE_EWA_SURFEL, c.SC_MODE_EWA_PIXEL],
                   [0, 1, 2, 3, 4]);
  assert.deepEqual([c.SC_FLAG_BACKFACE_CULL, c.SC_FLAG_EDGE_AA, c.SC_FLAG_TRANSLUCENT, c.SC_FLAG_LIT, c.SC_FLAG_SPECULAR,
                    c.SC_FLAG_CLIP], [1, 2, 4, 8, 16, 32]);
  assert.equal(c.SC_EDGE_RATIO_MAX, 4);
  assert.equal(c.SC_MAX_FILTER_PIXELS, 64);
});
