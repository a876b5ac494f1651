#version 450
// Per-surfel vertex for point primitives: 1-px points (kExpand = 0) draw
// directly; the geometry-shader expansion (kExpand = 1) passes the surfel on.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"
#define SC_SURFEL_VERTICES 1
#include "surfel_input.glsl"

layout(constant_id = 1) const int kExpand = 0;

layout(location = 0) out vec2 outY;
layout(location = 1) flat out vec3 outColor;
layout(location = 2) flat out vec3 outNormal;
layout(location = 3) flat out float outAmplitude;
layout(location = 4) flat out vec4 outPositionRadius;
layout(location = 5) flat out uint outPackedNormal;
layout(location = 6) flat out float outWeight;
layout(location = 7) flat out uint outPackedEdge;
#ifdef SC_LAYERED  // translucent frames' variant (client/CMakeLists.txt)
layout(location = 8) flat out float outAlpha;
#endif

void main() {
    loadSurfel();
    outY = vec2(0);
    outColor = inColor.rgb;
    outAmplitude = 1.0;
    outPositionRadius = inPositionRadius;
    outPackedNormal = inNormal;
    outWeight = inWeight;
    outPackedEdge = inEdge;
#ifdef SC_LAYERED
    outAlpha = inColor.a * frameOpacity();
#endif
    vec3 o = toCamera(inPositionRadius.xyz);
    vec3 n = rotateToCamera(decodeNormal(inNormal));
    outNormal = dot(n, o) > 0.0 ? -n : n;
    bool ok = finite3(o) && o.z >= frame.viewport.w && finite3(n) && !culledAsBackface(n, o) &&
              !outsideClip(inPositionRadius.xyz);
    gl_Position = ok && kExpand == 0 ? project(o) : kCulled;
    gl_PointSize = 1.0;
}
