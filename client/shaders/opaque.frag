#version 450
// Points and circles: opaque, nearest wins (depth write), weight 1.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(constant_id = 2) const bool kCircle = false;

layout(location = 0) in vec2 inY;
layout(location = 1) flat in vec3 inColor;
layout(location = 2) flat in vec3 inNormal;

layout(location = 0) out vec4 outColorWeight;
layout(location = 1) out vec4 outNormalWeight;

void main() {
    if (kCircle && dot(inY, inY) > 1.0) discard;
    outColorWeight = vec4(inColor, 1.0);
    outNormalWeight = vec4(inNormal, 1.0);
}
