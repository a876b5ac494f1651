// What surfels are coloured by, and the palettes: twins of
// client/render/coloring.cpp, so the browser and the Vulkan client draw the
// same colours.

import { attribute, type TilesetInfo } from "./format.js";

export type ColorBy = "auto" | "rgb" | "intensity" | "elevation" | "classification" | "return";
export const kColorByOrder: ColorBy[] = ["rgb", "intensity", "elevation", "classification", "return"];

// The colouring a set can show for `by`, or why not.
export function resolveColorBy(by: ColorBy, info: TilesetInfo): ColorBy | string {
  const intensity = attribute(info, "intensity") !== undefined;
  if (by === "auto") return info.colorBits ? "rgb" : intensity ? "intensity" : "elevation";
  const lacks = by === "rgb" && !info.colorBits ? "colour"
    : by === "intensity" && !intensity ? "intensity"
    : by === "classification" && !attribute(info, "classification") ? "classification"
    : by === "return" && !attribute(info, "return_number") ? "return numbers"
    : null;
  return lacks ? `colour by ${by}: the set stores no ${lacks}` : by;
}

export type RGB = [number, number, number];

export function viridis(t: number): RGB {
  // matplotlib's viridis at t = 0, 0.1, ..., 1, linearly interpolated (client/render/coloring.cpp).
  const k = [[0.267, 0.005, 0.329], [0.283, 0.141, 0.458], [0.254, 0.265, 0.53], [0.207, 0.372, 0.553],
             [0.164, 0.471, 0.558], [0.128, 0.567, 0.551], [0.135, 0.659, 0.518], [0.267, 0.749, 0.441],
             [0.478, 0.821, 0.318], [0.741, 0.873, 0.15], [0.993, 0.906, 0.144]];
  t = Math.min(Math.max(Number.isFinite(t) ? t : 0, 0), 1) * 10;
  const i = Math.min(Math.floor(t), 9), f = t - i;
  const a = k[i], b = k[i + 1];
  return [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f];
}

const kClassPalette: RGB[] = [
  [0.5, 0.5, 0.5], [0.7, 0.7, 0.7], [0.63, 0.43, 0.22], [0.56, 0.85, 0.44], [0.27, 0.7, 0.24], [0.09, 0.45, 0.13],
  [0.9, 0.25, 0.2], [0.95, 0.35, 0.85], [0.95, 0.8, 0.2], [0.2, 0.45, 0.95], [0.55, 0.35, 0.6], [0.35, 0.35, 0.4],
  [0.95, 0.95, 0.6], [0.95, 0.7, 0.3], [0.95, 0.55, 0.1], [0.75, 0.2, 0.45], [0.85, 0.6, 0.75], [0.45, 0.4, 0.35],
  [1, 0, 0],
];

export function classColor(c: number): RGB {
  if (c >= 0 && c < 19) return kClassPalette[c];
  const h = (((c * 0.618034) % 1) + 1) % 1 * 6;
  const ch = (o: number) => Math.min(Math.max(Math.abs(((h + o) % 6) - 3) - 1, 0), 1) * 0.7 + 0.2;
  return [ch(0), ch(4), ch(2)];
}

export function returnColor(number: number, count: number): RGB {
  if (count <= 1) return [0.95, 0.85, 0.25];
  if (number <= 1) return [0.9, 0.25, 0.2];
  if (number >= count) return [0.2, 0.4, 0.95];
  return [0.25, 0.8, 0.3];
}

export function intensityColor(value: number, p2: number, p98: number): RGB {
  const range = p98 - p2;
  const t = range > 0 ? (value - p2) / range : 0.5;
  const g = Math.pow(Math.min(Math.max(t, 0), 1), 1 / 2.2);
  return [g, g, g];
}
