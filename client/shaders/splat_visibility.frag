#version 450
// Pass 1: depth only, elliptical (Ren 2002 §5.1).
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(location = 0) in vec2 inY;

void main() {
    if (dot(inY, inY) > 2.0 * frame.kernel.y) discard;
}
