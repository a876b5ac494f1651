#version 450
// Pass 2: additive EWA accumulation of colour*w, w and normal*w (Ren 2002 §5.2),
// and of the unscaled kernel exp(-q/2), which measures coverage: the weights'
// scale shrinks with minification, so sum(w) cannot tell surface from fringe.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(location = 0) in vec2 inY;
layout(location = 1) flat in vec3 inColor;
layout(location = 2) flat in vec3 inNormal;
layout(location = 3) flat in float inAmplitude;
layout(location = 4) in vec2 inEdgeUV;
layout(location = 5) flat in uint inEdge;

layout(location = 0) out vec4 outColorWeight;
layout(location = 1) out vec4 outNormalWeight;

void main() {
    float q = dot(inY, inY);
    if (q > 2.0 * frame.kernel.y) discard;
    float g = exp(-0.5 * q);
    float w = inAmplitude * g * edgeFactor(inEdge, inEdgeUV);
    outColorWeight = vec4(inColor * w, w);
#ifdef SC_UNSIGNED_TARGETS
    // RGBA8 targets (a browser without float blending) clamp negative sums:
    // the normal goes as (n + 1) / 2 · w, and resolve.frag takes 2 Σ(...) - Σw.
    outNormalWeight = vec4((0.5 * inNormal + 0.5) * w, g);
#else
    outNormalWeight = vec4(inNormal * w, g);
#endif
}
