#version 450
// Picking (the browser's: web/src/renderer.ts pick; the Vulkan client has no
// picking pass): the nearest splat under the pixel, by its own depth (no
// z_t offset), within its ellipse y'y <= 2c, as (node + 1, surfel index in
// the node); the cleared (0, 0) where none covers the pixel.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(location = 0) in vec2 inY;
layout(location = 9) flat in uint inSurfel;

layout(location = 0) out uvec2 outId;

#ifdef SC_GLSL_ES
uniform uint scPickNode;  // the node's place in the draw list
#else
layout(constant_id = 2) const uint scPickNode = 0u;
#endif

void main() {
    if (dot(inY, inY) > 2.0 * frame.kernel.y) discard;
    outId = uvec2(scPickNode + 1u, inSurfel);
}
