// What surfels are coloured by, and the palettes: twins of
// client/render/coloring.cpp, with the palettes' colours read from the one
// file both clients take them from (common/render_defaults.json).

import defaults from "../../common/render_defaults.json";
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

// The palettes, from the file the C++ client's are generated from.
const { viridis: kViridis, classes: kClasses, returns: kReturns } = defaults.palettes;

export function viridis(t: number): RGB {
  // Stops at t = 0, 0.1, ..., 1, linearly interpolated.
  t = Math.min(Math.max(Number.isFinite(t) ? t : 0, 0), 1) * 10;
  const i = Math.min(Math.floor(t), 9), f = t - i;
  const a = kViridis[i], b = kViridis[i + 1];
  return [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f];
}

export function classColor(c: number): RGB {
  if (c >= 0 && c < kClasses.length) return kClasses[c].rgb as RGB;
  const h = (((c * 0.618034) % 1) + 1) % 1 * 6;
  const ch = (o: number) => Math.min(Math.max(Math.abs(((h + o) % 6) - 3) - 1, 0), 1) * 0.7 + 0.2;
  return [ch(0), ch(4), ch(2)];
}

// ASPRS's name of class c (LAS 1.4 R15 table 17), "class c" past 18.
export function className(c: number): string {
  return c >= 0 && c < kClasses.length ? kClasses[c].name : `class ${c}`;
}

export function returnColor(number: number, count: number): RGB {
  if (count <= 1) return kReturns.single as RGB;
  if (number <= 1) return kReturns.first as RGB;
  if (number >= count) return kReturns.last as RGB;
  return kReturns.intermediate as RGB;
}

export function intensityColor(value: number, p2: number, p98: number): RGB {
  const range = p98 - p2;
  const t = range > 0 ? (value - p2) / range : 0.5;
  const g = Math.pow(Math.min(Math.max(t, 0), 1), 1 / 2.2);
  return [g, g, g];
}
