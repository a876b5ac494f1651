#version 450
// Translucent frames, the visibility pass of layer k > 0 (depth peeling): as
// splat_visibility.frag, but fragments at or in front of layer k-1's
// pushed-back surface belong to the layers already drawn and are skipped, so
// the depth left is that of the nearest surface behind them, pushed back.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(set = 0, binding = 0) uniform sampler2D previousDepth;

layout(location = 0) in vec2 inY;
layout(location = 7) noperspective in float inDepth;  // the fragment's own depth, not pushed back

void main() {
    if (dot(inY, inY) > 2.0 * frame.kernel.y) discard;
    if (inDepth >= texelFetch(previousDepth, ivec2(gl_FragCoord.xy), 0).r) discard;
}
