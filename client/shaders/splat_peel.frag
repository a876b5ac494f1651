#version 450
// Translucent frames, the visibility pass of layer k > 0 (depth peeling): as
// splat_visibility.frag, but fragments at or in front of layer k-1's
// pushed-back surface belong to the layers already drawn and are skipped, so
// the depth left is that of the nearest surface behind them, pushed back.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(set = 0, binding = 0) uniform sampler2D previousDepth;

layout(location = 0) in vec2 inY;
// The fragment's own depth, not pushed back.
#ifdef SC_GLSL_ES  // splat_quad.vert says why
layout(location = 7) in float inDepthW;
layout(location = 8) in float inW;
float ownDepth() { return inDepthW / inW; }
#else
layout(location = 7) noperspective in float inDepth;
float ownDepth() { return inDepth; }
#endif

void main() {
    if (dot(inY, inY) > 2.0 * frame.kernel.y) discard;
    if (ownDepth() >= texelFetch(previousDepth, ivec2(gl_FragCoord.xy), 0).r) discard;
}
