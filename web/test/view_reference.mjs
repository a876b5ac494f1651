// The browser viewer's converged images against the Vulkan client's
// (surfcast-view --headless) at the same camera and size: the reference, the
// comparison and its limits, and a page's problems. Shared by the web tests.

import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { readFileSync } from "node:fs";
import { PNG } from "pngjs";

// surfcast-view's converged frame of the set at `url` (`bin`: its path), at
// `camera` and `size`, with `extra` arguments, written to `out`: its JSON
// summary (splats, nodes, nodes_crc, converged) and the image.
export function viewReference(bin, url, { camera, size, out, extra = [] }) {
  const lines = execFileSync(bin, ["--headless", url, "--lod", "1", "--camera", camera, "--size", `${size.width}x${size.height}`,
    "--out", out, ...extra], { encoding: "utf8" }).trim().split("\n");
  return { json: JSON.parse(lines[lines.length - 1]), png: PNG.sync.read(readFileSync(out)) };
}

// Mean absolute difference over RGB (0-255), and the share of pixels that
// differ by more than 16 in some channel.
export function compare(a, b) {
  assert.equal(a.width, b.width);
  assert.equal(a.height, b.height);
  let sum = 0, far = 0;
  for (let i = 0; i < a.data.length; i += 4) {
    let most = 0;
    for (let c = 0; c < 3; ++c) {
      const d = Math.abs(a.data[i + c] - b.data[i + c]);
      sum += d;
      most = Math.max(most, d);
    }
    if (most > 16) ++far;
  }
  const pixels = a.width * a.height;
  return { mean: sum / (3 * pixels), far: far / pixels };
}

// Both clients draw the same nodes (the same LOD rules at the same camera)
// with the same EWA math in float32. What may differ: the rasterizers'
// rules for pixels whose centre lies on a splat quad's edge (lavapipe
// against SwiftShader), the order of the float additions (the Vulkan
// client Morton-orders each node's surfels, the browser keeps Draco's
// order), and the final rounding to 8 bits. Rounding and order move a pixel
// by about one level, so a mean under 1 of 255 leaves no room for a
// systematic error (a missing normalization, a wrong axis or offset moves
// most covered pixels by tens of levels); a quad edge moves a single pixel
// by up to the checkerboard's full contrast, and such pixels stay under
// 1 % of the image.
export const kMeanLimit = 1.0, kFarLimit = 0.01;

export async function waitFor(predicate, what, ms = 10000) {
  const end = Date.now() + ms;
  while (Date.now() < end) {
    const v = predicate();
    if (v) return v;
    await new Promise((r) => setTimeout(r, 50));
  }
  throw new Error(`timed out waiting for ${what}`);
}

// The page's problems from now on, as they happen: console errors, page
// errors, failed requests and HTTP error responses.
export function watchProblems(page) {
  const problems = [];
  page.on("console", (m) => m.type() === "error" && problems.push(`console: ${m.text()}`));
  page.on("pageerror", (e) => problems.push(`page error: ${e.message}`));
  page.on("requestfailed", (r) => problems.push(`request failed: ${r.url()} ${r.failure()?.errorText}`));
  page.on("response", (r) => r.status() >= 400 && problems.push(`HTTP ${r.status()}: ${r.url()}`));
  return problems;
}
