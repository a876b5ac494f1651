#version 450
// Quad expansion: Vulkan draws one instance per surfel, 4 strip vertices each;
// the browser's GLSL ES two triangles per surfel (surfel_input.glsl).
// kPass 0: visibility (pushed back), 1: accumulation, 2: circles.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"
#define SC_SURFEL_VERTICES 6
#include "surfel_input.glsl"

layout(constant_id = 0) const int kPass = 1;

layout(location = 0) out vec2 outY;
layout(location = 1) flat out vec3 outColor;
layout(location = 2) flat out vec3 outNormal;
layout(location = 3) flat out float outAmplitude;
layout(location = 4) out vec2 outEdgeUV;
layout(location = 5) flat out uint outEdge;
#ifdef SC_LAYERED  // translucent frames' variant (client/CMakeLists.txt)
layout(location = 6) flat out float outAlpha;         // opacity: stored times frameOpacity()
#ifdef SC_GLSL_ES
// No noperspective in GLSL ES: the depth goes as depth * w and w, both
// perspective-correct, whose ratio is exactly the screen-linear depth.
layout(location = 7) out float outDepthW;
layout(location = 8) out float outW;
#define SET_DEPTH(depth, w) outDepthW = (depth) * (w); outW = (w)
#else
layout(location = 7) noperspective out float outDepth; // depth (near / z) of the splat itself, not pushed back
#define SET_DEPTH(depth, w) outDepth = (depth)
#endif
#define LAYERED(statement) statement
#else
#define LAYERED(statement)
#endif
#ifdef SC_PICK  // the browser's picking pass (splat_pick.frag)
layout(location = 9) flat out uint outSurfel;
#define PICK(statement) statement
#else
#define PICK(statement)
#endif

void main() {
    loadSurfel();
    outColor = inColor.rgb;
    LAYERED(outAlpha = inColor.a * frameOpacity());
    LAYERED(SET_DEPTH(0.0, 1.0));
    outEdgeUV = vec2(0);
    outEdge = 0u;
    PICK(outSurfel = surfelIndex());
    if (kPass == 2) {
        vec3 o = toCamera(inPositionRadius.xyz);
        vec3 n = rotateToCamera(decodeNormal(inNormal));
        bool ok = finite3(o) && o.z >= frame.viewport.w && finite3(n) && !culledAsBackface(n, o) &&
                  !outsideClip(inPositionRadius.xyz);
        gl_Position = ok ? circleCorner(o, splatRadius(inPositionRadius.w, o.z), cornerIndex(), outY) : kCulled;
        outNormal = dot(n, o) > 0.0 ? -n : n;
        outAmplitude = 1.0;
        return;
    }
    Splat sp;
    if (!setupSplat(inPositionRadius.xyz, inPositionRadius.w, inNormal, inWeight, inEdge, sp)) {
        gl_Position = kCulled;
        outY = vec2(0);
        outNormal = vec3(0);
        outAmplitude = 0.0;
        return;
    }
    vec3 p = splatCorner(sp, cornerIndex(), outY, outEdgeUV);
    float ownDepth = frame.viewport.w / p.z;  // 1/z is affine in screen space: noperspective interpolates it exactly
    outEdge = sp.edge;
    if (kPass == 0) p = pushBack(sp, p);
    gl_Position = project(p);
    LAYERED(SET_DEPTH(ownDepth, gl_Position.w));
    outNormal = sp.n;
    outAmplitude = sp.amplitude;
}
