// Shared by the resolve shaders (resolve.frag, resolve_layer.frag): edge
// antialiasing's coverage and deferred shading, twins of the CPU reference's
// resolve and of shadePixel in client/render/render_settings.cpp.

const float kAmbient = 0.25, kDiffuse = 0.75, kSpecular = 0.3, kShininess = 32.0;

// Edge antialiasing: partial coverage g / tau on the covered region's border
// only (a pixel with an uncovered 4-neighbour in `kernelSums`, whose alpha is
// the summed exp(-q/2)); inside, a low sum is sparse sampling or a fold the
// visibility pass thinned, not an edge.
float edgeCoverage(sampler2D kernelSums, ivec2 pixel, float g) {
    if ((frame.flags & SC_FLAG_EDGE_AA) == 0u || !(g < frameEdgeTau())) return 1.0;
    ivec2 last = textureSize(kernelSums, 0) - 1;
    bool border = false;
    for (int k = 0; k < 4; ++k) {
        ivec2 q = clamp(pixel + ivec2(k == 0 ? 1 : k == 1 ? -1 : 0, k == 2 ? 1 : k == 3 ? -1 : 0), ivec2(0), last);
        border = border || !(texelFetch(kernelSums, q, 0).a > 0.0);
    }
    return border ? g / frameEdgeTau() : 1.0;
}

// Deferred shading of the normalized colour with the filtered camera-space
// normal (any length); the light sits at the eye.
vec3 shade(vec3 color, vec3 normalSum) {
    if ((frame.flags & SC_FLAG_LIT) == 0u) return color;
    float eta = frame.viewport.x;
    vec3 ray = vec3((gl_FragCoord.x - 0.5 * frame.viewport.y) / eta, kYSign * (gl_FragCoord.y - 0.5 * frame.viewport.z) / eta, 1.0);
    vec3 n = dot(normalSum, normalSum) > 0.0 ? normalize(normalSum) : vec3(0);
    float ndotv = abs(dot(n, -normalize(ray)));
    vec3 lit = color * (kAmbient + kDiffuse * ndotv);
    if ((frame.flags & SC_FLAG_SPECULAR) != 0u) lit += vec3(kSpecular * pow(ndotv, kShininess));
    return min(lit, vec3(1.0));
}
