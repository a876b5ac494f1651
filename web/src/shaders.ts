// The constants client/shaders/shared_types.h defines for both languages, from
// the module "surfcast:shaders" that build.mjs bundles (the shaders, generated
// from client/shaders by web/glsl_es.mjs, renderer.ts imports itself). No
// exported type names that build-time module: the npm package's declarations
// must type-check without it.

import { constants } from "surfcast:shaders";

function constant(name: string): number {
  const v = constants[name];
  if (v === undefined) throw new Error(`shared_types.h defines no ${name}`);
  return v;
}
export const kModePoints = constant("SC_MODE_POINTS"), kModeCircles = constant("SC_MODE_CIRCLES");
export const kModeEwaNoPrefilter = constant("SC_MODE_EWA_NOPREFILTER"), kModeEwaSurfel = constant("SC_MODE_EWA_SURFEL");
export const kModeEwaPixel = constant("SC_MODE_EWA_PIXEL");
export const kFlagBackfaceCull = constant("SC_FLAG_BACKFACE_CULL"), kFlagEdgeAA = constant("SC_FLAG_EDGE_AA");
export const kFlagLit = constant("SC_FLAG_LIT"), kFlagSpecular = constant("SC_FLAG_SPECULAR");
export const kFlagClip = constant("SC_FLAG_CLIP");
