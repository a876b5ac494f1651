#version 450
// Translucent frames, after each layer's accumulation: the layer normalized
// and shaded as resolve.frag does, with opacity = sum(alpha w) / sum(w) times
// edge antialiasing's coverage, premultiplied and blended under the layers in
// front of it (front to back: dst += (1 - dst.a) src), which is eq. 12 of
// Zwicker 2001 evaluated in the other order.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"
#include "resolve_common.glsl"

layout(set = 0, binding = 0) uniform sampler2D colorWeight;
layout(set = 0, binding = 1) uniform sampler2D normalWeight;
layout(set = 0, binding = 2) uniform sampler2D alphaWeight;

layout(location = 0) out vec4 outColor;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 cw = texelFetch(colorWeight, pixel, 0);
    vec4 nw = texelFetch(normalWeight, pixel, 0);
    if (!(nw.a > 0.0) || !(cw.a > 0.0)) discard;
    // ewa-surfel's weights sum to about 1 rather than being divided by: its
    // colour is normalized here too, as a layer has no background of its own.
    vec3 color = shade(cw.rgb / cw.a, nw.xyz);
    float alpha = clamp(texelFetch(alphaWeight, pixel, 0).r / cw.a, 0.0, 1.0) * edgeCoverage(normalWeight, pixel, nw.a);
    outColor = vec4(color * alpha, alpha);
}
