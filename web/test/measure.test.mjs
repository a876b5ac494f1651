// The measuring tools' math (web/src/measure.ts) under node, against values
// derived by hand.

import { test } from "node:test";
import assert from "node:assert/strict";
import { loadModule } from "./load_module.mjs";

const close = (got, want, what) => assert.ok(Math.abs(got - want) < 1e-9, `${what}: ${got}, expected ${want}`);

test("distance, height difference and polyline length", async () => {
  const { distance, heightDifference, polylineLength } = await loadModule("src/measure.ts");
  close(distance([1, 2, 3], [4, 6, 3]), 5, "a 3-4-5 triangle's hypotenuse");
  close(distance([1e6, 2e6, 10], [1e6 + 3, 2e6 + 4, 10]), 5, "the same far from the origin");
  close(heightDifference([0, 0, 7], [9, 9, 2]), 5, "|2 - 7|");
  close(polylineLength([[0, 0, 0], [3, 4, 0], [3, 4, 12]]), 5 + 12, "two legs");
  close(polylineLength([[1, 1, 1]]), 0, "one point");
});

test("area: any plane, any winding, and angles", async () => {
  const { polygonArea, angleAt, measure } = await loadModule("src/measure.ts");
  close(polygonArea([[0, 0, 0], [2, 0, 0], [2, 3, 0], [0, 3, 0]]), 6, "a 2 x 3 rectangle");
  close(polygonArea([[0, 3, 0], [2, 3, 0], [2, 0, 0], [0, 0, 0]]), 6, "the same, clockwise");
  // A 2 x 2 square tilted 45 degrees about x: its corners (0,0,0), (2,0,0),
  // (2, sqrt2, sqrt2), (0, sqrt2, sqrt2); its footprint on the ground is 2 x sqrt2.
  const r = Math.SQRT2;
  close(polygonArea([[0, 0, 0], [2, 0, 0], [2, r, r], [0, r, r]]), 4, "a tilted square");
  close(polygonArea([[0, 0, 5], [4, 0, 5], [0, 3, 5]]), 6, "a 3-4-5 right triangle");
  close(polygonArea([[0, 0, 0], [1, 1, 1]]), 0, "two points");
  close(angleAt([1, 0, 0], [0, 0, 0], [0, 0, 1]), 90, "a right angle");
  close(angleAt([1, 0, 0], [0, 0, 0], [0.5, Math.sqrt(3) / 2, 0]), 60, "an equilateral triangle's corner");
  close(angleAt([-1, 0, 0], [0, 0, 0], [1, 0, 0]), 180, "a straight line");
  close(angleAt([0, 0, 0], [0, 0, 0], [1, 0, 0]), 0, "a degenerate ray");
  assert.equal(measure("distance", [[0, 0, 0], [3, 4, 0]], "m").label, "5.000 m");
  assert.equal(measure("height", [[0, 0, 1], [3, 4, 3.5]]).label, "Δz 2.500");
  assert.equal(measure("area", [[0, 0, 0], [2, 0, 0], [2, 3, 0]], "m").label, "3.000 m²");
  assert.equal(measure("angle", [[1, 0, 0], [0, 0, 0], [0, 2, 0]]).label, "90.00°");
});
