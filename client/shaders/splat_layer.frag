#version 450
// Translucent frames, the accumulation pass of one layer: as
// splat_accumulate.frag (the depth test keeps fragments within z_t of the
// layer's surface; the last layer tests none and takes every fragment behind
// the layers before it), plus the opacity's sum, and without the fragments of
// the layers in front (at or nearer than layer k-1's pushed-back surface).
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(set = 0, binding = 0) uniform sampler2D previousDepth;

layout(location = 0) in vec2 inY;
layout(location = 1) flat in vec3 inColor;
layout(location = 2) flat in vec3 inNormal;
layout(location = 3) flat in float inAmplitude;
layout(location = 4) in vec2 inEdgeUV;
layout(location = 5) flat in uint inEdge;
layout(location = 6) flat in float inAlpha;

layout(location = 0) out vec4 outColorWeight;
layout(location = 1) out vec4 outNormalWeight;
layout(location = 2) out float outAlphaWeight;

void main() {
    float q = dot(inY, inY);
    if (q > 2.0 * frame.kernel.y) discard;
    if (frame.layer > 0u && gl_FragCoord.z >= texelFetch(previousDepth, ivec2(gl_FragCoord.xy), 0).r) discard;
    float g = exp(-0.5 * q);
    float w = inAmplitude * g * edgeFactor(inEdge, inEdgeUV);
    outColorWeight = vec4(inColor * w, w);
    outNormalWeight = vec4(inNormal * w, g);
    outAlphaWeight = inAlpha * w;
}
