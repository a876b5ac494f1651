#version 450
// Pass 3: normalization and deferred shading (twin of shadePixel in
// client/render/render_settings.cpp and of the CPU reference's resolve).
// Output alpha is coverage: 1 where the summed kernels show the surface, in
// between at silhouettes with edge antialiasing.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(set = 0, binding = 0) uniform sampler2D colorWeight;
layout(set = 0, binding = 1) uniform sampler2D normalWeight;

layout(location = 0) out vec4 outColor;

const float kAmbient = 0.25, kDiffuse = 0.75, kSpecular = 0.3, kShininess = 32.0;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 cw = texelFetch(colorWeight, pixel, 0);
    vec4 nw = texelFetch(normalWeight, pixel, 0);
    vec3 background = frame.resolve.rgb;
    if (!(nw.a > 0.0) || !(cw.a > 0.0)) {
        outColor = vec4(background, 0.0);
        return;
    }
    // Edge antialiasing: partial coverage on the covered region's border only
    // (a pixel with an uncovered 4-neighbour); inside, a low sum is sparse
    // sampling or a fold the visibility pass thinned, not an edge.
    float coverage = 1.0;
    if ((frame.flags & SC_FLAG_EDGE_AA) != 0u && nw.a < frame.resolve.a) {
        ivec2 last = textureSize(normalWeight, 0) - 1;
        bool border = false;
        for (int k = 0; k < 4; ++k) {
            ivec2 q = clamp(pixel + ivec2(k == 0 ? 1 : k == 1 ? -1 : 0, k == 2 ? 1 : k == 3 ? -1 : 0), ivec2(0), last);
            border = border || !(texelFetch(normalWeight, q, 0).a > 0.0);
        }
        if (border) coverage = nw.a / frame.resolve.a;
    }
    vec3 color;
    if (frame.mode == SC_MODE_EWA_SURFEL) {
        // Per-surfel weights: no division; where the weights fall short of 1
        // (the surface's edge) the background shows through.
        color = cw.rgb + max(1.0 - cw.a, 0.0) * background;
    } else {
        color = cw.rgb / cw.a;
    }
    if (frame.shading != SC_SHADING_UNLIT) {
        float eta = frame.viewport.x;
        vec3 ray = vec3((gl_FragCoord.x - 0.5 * frame.viewport.y) / eta, -(gl_FragCoord.y - 0.5 * frame.viewport.z) / eta, 1.0);
        vec3 n = dot(nw.xyz, nw.xyz) > 0.0 ? normalize(nw.xyz) : vec3(0);
        float ndotv = abs(dot(n, -normalize(ray)));
        vec3 lit = color * (kAmbient + kDiffuse * ndotv);
        if (frame.shading == SC_SHADING_PHONG) lit += vec3(kSpecular * pow(ndotv, kShininess));
        color = min(lit, vec3(1.0));
    }
    outColor = vec4(mix(background, color, coverage), coverage);
}
