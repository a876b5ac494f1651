// Modules build.mjs generates at build time (an esbuild plugin).
declare module "surfcast:shaders" {
  // [vertex, fragment] GLSL ES 3.00 sources of each program (web/glsl_es.mjs).
  export const programs: Record<"visibility" | "accumulate" | "accumulate8" | "circles" | "points" | "resolve" | "resolve8" |
    "peel" | "layer" | "resolveLayer" | "composite" | "pick" | "resolveOver" | "resolveOver8", [string, string]>;
  // client/shaders/shared_types.h's #defines (SC_MODE_EWA_PIXEL ...), by name.
  export const constants: Record<string, number>;
}
