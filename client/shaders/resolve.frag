#version 450
// Pass 3: normalization and deferred shading (twin of shadePixel in
// client/render/render_settings.cpp and of the CPU reference's resolve).
// Output alpha is coverage: 1 where the summed kernels show the surface, in
// between at silhouettes with edge antialiasing (SC_OVER_SCENE, ewa-surfel:
// times the weights' sum, up to 1).
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"
#include "resolve_common.glsl"

layout(set = 0, binding = 0) uniform sampler2D colorWeight;
layout(set = 0, binding = 1) uniform sampler2D normalWeight;

layout(location = 0) out vec4 outColor;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 cw = texelFetch(colorWeight, pixel, 0);
    vec4 nw = texelFetch(normalWeight, pixel, 0);
    vec3 background = frameBackground();
    if (!(nw.a > 0.0) || !(cw.a > 0.0)) {
        outColor = vec4(background, 0.0);
        return;
    }
    float coverage = edgeCoverage(normalWeight, pixel, nw.a);
    vec3 color;
    if (frame.mode == SC_MODE_EWA_SURFEL) {
        // Per-surfel weights: no division; where the weights fall short of 1
        // (the surface's edge) the background shows through.
        color = cw.rgb + max(1.0 - cw.a, 0.0) * background;
    } else {
        color = cw.rgb / cw.a;
    }
#ifdef SC_UNSIGNED_TARGETS  // splat_accumulate.frag says why
    color = shade(color, 2.0 * nw.xyz - cw.a);
#else
    color = shade(color, nw.xyz);
#endif
    float alpha = coverage;
#ifdef SC_OVER_SCENE  // the browser's three.js layer: blended premultiplied over a scene (background black)
    if (frame.mode == SC_MODE_EWA_SURFEL) alpha *= clamp(cw.a, 0.0, 1.0);  // the weights' shortfall shows the scene
#endif
    outColor = vec4(mix(background, color, coverage), alpha);
}
