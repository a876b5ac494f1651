// The browser's shaders, generated from the Vulkan client's GLSL 4.50 sources
// (client/shaders): one source per pass for both clients. The differences of
// the two APIs are blocks under SC_GLSL_ES in those sources (splat_common.glsl
// names them); what this generator does is only what GLSL ES 3.00's syntax
// requires:
// - includes inlined, comments dropped (the sources keep them), #version 300
//   es, default precisions, SC_GLSL_ES and the variant's defines first;
// - specialization constants become constants of the variant's values;
// - varyings lose their locations, which GLSL ES does not take, and are named
//   by location (sc_vN) on both sides, as Vulkan matches them;
// - sampler bindings lose their set and binding; gl_VertexIndex is gl_VertexID.
// build.mjs bundles the result (an esbuild plugin); web/test/shaders.test.mjs
// compiles every variant with glslangValidator.

import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

export const shaderDir = join(dirname(fileURLToPath(import.meta.url)), "..", "client", "shaders");

function inlineIncludes(file, including = []) {
  if (including.includes(file)) throw new Error(`${[...including, file].join(" includes ")}: a cycle`);
  return readFileSync(join(shaderDir, file), "utf8")
    .replace(/^#include "([^"]+)"[ \t]*(\/\/.*)?$/gm, (_, name) => inlineIncludes(name, [...including, file]));
}

// A specialization constant's value written as GLSL of its type (GLSL ES
// converts no int to float: 1 must be 1.0 for a float).
function literal(type, value) {
  if (type === "float") return Number.isInteger(value) ? `${value}.0` : String(value);
  if (type === "bool") return value ? "true" : "false";
  if (!Number.isInteger(value)) throw new Error(`${value} is not an ${type}`);
  return type === "uint" ? `${value}u` : String(value);
}

// The GLSL ES 3.00 text of `file` (a stage of client/shaders) for one variant:
// `constants` gives specialization constants by name, `defines` macros to set.
export function glslEs(file, { constants = {}, defines = [] } = {}) {
  const stage = file.slice(file.lastIndexOf(".") + 1);
  if (stage !== "vert" && stage !== "frag") throw new Error(`${file}: WebGL2 has vertex and fragment shaders only`);
  let text = inlineIncludes(file)
    .replace(/\s*\/\/.*$/gm, "")  // comments: the sources' own say what the code does
    .replace(/^#version 450\n/m, "")
    .replace(/^#extension GL_GOOGLE_include_directive : require\n/m, "")
    .replaceAll("gl_VertexIndex", "gl_VertexID")
    .replace(/layout\(set = \d+, binding = \d+\) uniform (\w+) (\w+);/g, "uniform highp $1 $2;");
  const unused = new Set(Object.keys(constants));
  text = text.replace(/layout\(constant_id = \d+\) const (\w+) (\w+) = ([^;]+);/g, (_, type, name, value) => {
    unused.delete(name);
    return `const ${type} ${name} = ${name in constants ? literal(type, constants[name]) : value};`;
  });
  if (unused.size) throw new Error(`${file}: no specialization constant ${[...unused].join(", ")}`);
  // Varyings: a vertex shader's outputs, a fragment shader's inputs.
  const varying = stage === "vert" ? "out" : "in";
  const renames = new Map();
  text = text.replace(new RegExp(`layout\\(location = (\\d+)\\) ((?:flat |noperspective )?)${varying} (\\w+) (\\w+);`, "g"),
    (_, location, qualifier, type, name) => {
      renames.set(name, `sc_v${location}`);
      return `${qualifier}${varying} ${type} sc_v${location};`;
    });
  for (const [from, to] of renames) text = text.replace(new RegExp(`\\b${from}\\b`, "g"), to);
  const head = ["#version 300 es", "#define SC_GLSL_ES 1", ...defines.map((d) => `#define ${d} 1`),
    "precision highp float;", "precision highp int;", "precision highp sampler2D;", "precision highp usampler2D;"];
  return `${head.join("\n")}\n${text}`;
}

// The constants shared_types.h defines for both languages (SC_MODE_EWA_PIXEL ...), by name.
export function sharedConstants() {
  const constants = {};
  for (const [, name, value] of readFileSync(join(shaderDir, "shared_types.h"), "utf8")
    .matchAll(/^#define (SC_\w+) ([0-9.]+)u?$/gm)) constants[name] = Number(value);
  return constants;
}

// Every program the browser's renderer links, as [vertex, fragment] sources
// (web/src/renderer.ts draws them; `unsigned8`: 8-bit targets without float
// blending).
export function programs() {
  const quad = (kPass, defines = []) => glslEs("splat_quad.vert", { constants: { kPass }, defines });
  const fullscreen = glslEs("fullscreen.vert");
  return {
    visibility: [quad(0), glslEs("splat_visibility.frag")],
    accumulate: [quad(1), glslEs("splat_accumulate.frag")],
    accumulate8: [quad(1), glslEs("splat_accumulate.frag", { defines: ["SC_UNSIGNED_TARGETS"] })],
    circles: [quad(2), glslEs("opaque.frag", { constants: { kCircle: true } })],
    points: [glslEs("splat_point.vert"), glslEs("opaque.frag")],
    resolve: [fullscreen, glslEs("resolve.frag")],
    resolve8: [fullscreen, glslEs("resolve.frag", { defines: ["SC_UNSIGNED_TARGETS"] })],
    resolveOver: [fullscreen, glslEs("resolve.frag", { defines: ["SC_OVER_SCENE"] })],
    resolveOver8: [fullscreen, glslEs("resolve.frag", { defines: ["SC_UNSIGNED_TARGETS", "SC_OVER_SCENE"] })],
    peel: [quad(0, ["SC_LAYERED"]), glslEs("splat_peel.frag")],
    layer: [quad(1, ["SC_LAYERED"]), glslEs("splat_layer.frag")],
    pick: [quad(1, ["SC_PICK"]), glslEs("splat_pick.frag")],
    resolveLayer: [fullscreen, glslEs("resolve_layer.frag")],
    composite: [fullscreen, glslEs("composite.frag")],
  };
}
