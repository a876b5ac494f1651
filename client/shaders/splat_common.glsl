// Shared by the splat shaders: frame parameters, transforms, unpacking, and the
// object-space EWA setup of Ren et al. 2002, §5.2 and appendix A (DESIGN.md,
// "Object-space EWA in one screen"). The CPU reference
// (client/render/cpu_reference.cpp) evaluates the same kernel in screen space.
// The browser's GLSL ES 3.00 is generated from these files (web/glsl_es.mjs),
// with SC_GLSL_ES defined: the blocks under it are the two APIs' differences.
#include "shared_types.h"

#ifdef SC_GLSL_ES
uniform FrameParams frame;
// Depth in [0, 1] straight from clip z where EXT_clip_control is present;
// without it, OpenGL maps clip z in [-w, w], and z_clip = 2 near - z gives
// the same window depth near / z.
uniform bool scClipControl;
float clipDepth(float z) { return scClipControl ? frame.viewport.w : 2.0 * frame.viewport.w - z; }
// Framebuffer y runs up in OpenGL.
const float kYSign = 1.0;
// GLSL ES 3.00 has no unpackUnorm4x8.
vec4 scUnpackUnorm4x8(uint v) { return vec4(v & 255u, (v >> 8) & 255u, (v >> 16) & 255u, v >> 24) / 255.0; }
#define unpackUnorm4x8 scUnpackUnorm4x8
#else
layout(push_constant) uniform Push { FrameParams frame; };
float clipDepth(float z) { return frame.viewport.w; }
// Framebuffer y runs down in Vulkan.
const float kYSign = -1.0;
#endif

vec3 toCamera(vec3 p) {
    vec4 q = vec4(p, 1.0);
    return vec3(dot(frame.view0, q), dot(frame.view1, q), dot(frame.view2, q));
}
vec3 rotateToCamera(vec3 v) {
    return vec3(dot(frame.view0.xyz, v), dot(frame.view1.xyz, v), dot(frame.view2.xyz, v));
}

// Reversed-Z perspective with an infinite far plane: depth = near / z, so
// float depth keeps its relative precision at every distance (the visibility
// offset z_t must survive the depth test far away too).
vec4 project(vec3 c) {
    float eta = frame.viewport.x;
    return vec4(2.0 * eta / frame.viewport.y * c.x, kYSign * 2.0 * eta / frame.viewport.z * c.y, clipDepth(c.z), c.z);
}
// A clip position outside the view volume: the primitive is dropped.
const vec4 kCulled = vec4(2.0, 2.0, 2.0, 1.0);

vec3 decodeNormal(uint packed) {
    vec2 e = unpackSnorm2x16(packed);
    vec3 n = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    float t = max(-n.z, 0.0);
    n.x += n.x >= 0.0 ? -t : t;
    n.y += n.y >= 0.0 ? -t : t;
    return normalize(n);
}

bool finite3(vec3 v) { return !any(isnan(v)) && !any(isinf(v)); }

// The clip box (SC_FLAG_CLIP): p, relative to the render origin, lies outside it.
bool outsideClip(vec3 p) {
    return (frame.flags & SC_FLAG_CLIP) != 0u && (any(lessThan(p, frame.clipMin.xyz)) || any(greaterThan(p, frame.clipMax.xyz)));
}
// The frame's packed scalars (FrameParams says why they are packed).
vec3 frameBackground() { return unpackUnorm4x8(frame.background).rgb; }
float frameEdgeTau() { return frame.clipMin.w; }
float frameOpacity() { return frame.clipMax.w; }

// Per-splat backface culling: n the camera-space normal as stored, o the
// camera-space centre (the eye at the origin).
bool culledAsBackface(vec3 n, vec3 o) { return (frame.flags & SC_FLAG_BACKFACE_CULL) != 0u && dot(n, o) > 0.0; }

// The splat radius at camera depth z: r, or one pixel's worth where r is 0,
// NaN or infinite (a degenerate h draws as a dot, never as NaN).
float splatRadius(float r, float z) { return r > 0.0 && !isinf(r) ? r : z / frame.viewport.x; }

vec3 tangentOf(vec3 n) {
    vec3 a = abs(n.x) < 0.9 ? vec3(1, 0, 0) : vec3(0, 1, 0);
    return normalize(cross(n, a));
}

// The splat's tangent-plane parallelogram in camera space: corner y in
// [-sqrt(2c), sqrt(2c)]^2 sits at o + y.x * axisU + y.y * axisV.
struct Splat {
    vec3 o;          // centre
    vec3 axisU, axisV;
    vec3 n;          // unit normal, facing the eye (splats are two-sided unless culled as backfaces)
    float amplitude; // weight at the centre
    vec3 edgeS, edgeT; // camera-space tangentOf basis of the world normal, scaled by 1/r (edge weights)
    uint edge;       // GpuSurfel::edge
    float r;         // reconstruction radius after the kernel scale
    float footprint; // max(Lambda0, Lambda1): r magnified, the low-pass filter's object extent minified
};

bool setupSplat(vec3 position, float radius, uint normal, float weight, uint edge, out Splat sp) {
    float eta = frame.viewport.x;
    vec3 o = toCamera(position);
    // Surfels behind the near plane (or NaN) are dropped; those straddling it
    // are clipped by the rasterizer, which is safe because o.z >= near > 0.
    if (!finite3(o) || !(o.z >= frame.viewport.w) || outsideClip(position)) return false;
    vec3 n = rotateToCamera(decodeNormal(normal));
    if (!finite3(n) || culledAsBackface(n, o)) return false;
    n = dot(n, o) > 0.0 ? -n : n;
    vec3 s = tangentOf(n), t = cross(n, s);
    float r = splatRadius(radius * frame.kernel.x, o.z);

    // J: columns d(screen)/du_s and d(screen)/du_t at the centre.
    float k = eta / (o.z * o.z);
    vec2 js = k * vec2(s.x * o.z - s.z * o.x, s.y * o.z - s.z * o.y);
    vec2 jt = k * vec2(t.x * o.z - t.z * o.x, t.y * o.z - t.z * o.y);
    // M = V^r + V^h J^-1 J^-T shares its eigenvectors with J'J (V^r = r^2 I
    // is isotropic), so Rot(theta) and Lambda come from J'J's eigensystem.
    float a = dot(js, js), b = dot(js, jt), c = dot(jt, jt);
    float mean = 0.5 * (a + c), dev = sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0));
    float l0 = mean + dev, l1 = max(mean - dev, 0.0);
    vec2 e0 = a >= c ? vec2(l0 - c, b) : vec2(b, l0 - a);
    e0 = dot(e0, e0) > 0.0 ? normalize(e0) : vec2(1, 0);
    vec2 e1 = vec2(-e0.y, e0.x);
    // Grazing angles: J'J is near singular and the low-pass filter's object
    // extent explodes; clamp it to SC_MAX_FILTER_PIXELS pixels at this depth.
    float lmin = eta / (SC_MAX_FILTER_PIXELS * o.z);
    lmin *= lmin;
    float lowpass = frame.kernel.w;
    float m0 = r * r + lowpass / max(l0, lmin), m1 = r * r + lowpass / max(l1, lmin);
    float L0 = sqrt(m0), L1 = sqrt(m1);
    sp.o = o;
    sp.n = n;
    // Edge weights live in the world normal's tangentOf basis (as captured by
    // client/capture/weight_capture.cpp), at distance r from the centre.
    sp.edge = frame.mode == SC_MODE_EWA_SURFEL ? edge : 0u;
    sp.edgeS = sp.edgeT = vec3(0);
    if (sp.edge != 0u) {
        vec3 nw = decodeNormal(normal), sw = tangentOf(nw);
        sp.edgeS = rotateToCamera(sw) / r;
        sp.edgeT = rotateToCamera(cross(nw, sw)) / r;
    }
    sp.r = r;
    sp.footprint = max(L0, L1);
    sp.axisU = L0 * (e0.x * s + e0.y * t);
    sp.axisV = L1 * (e1.x * s + e1.y * t);
    // G_M scaled by 2 pi r^2: peak 1 under magnification, a constant integral
    // under minification (where M grows with the low-pass filter).
    sp.amplitude = r * r / (L0 * L1) * (frame.mode == SC_MODE_EWA_SURFEL ? weight : 1.0);
    return finite3(sp.axisU) && finite3(sp.axisV) && !isnan(sp.amplitude) && !isinf(sp.amplitude);
}

// Corner `corner` (0..3, a triangle strip) of the splat: y, the edge-weight
// coordinates (tangent offset / r in the edge basis) and the camera position.
vec3 splatCorner(Splat sp, int corner, out vec2 y, out vec2 edgeUV) {
    vec2 v = vec2(corner & 1, corner >> 1);
    y = 2.0 * sqrt(2.0 * frame.kernel.y) * (v - 0.5);
    vec3 offset = y.x * sp.axisU + y.y * sp.axisV;
    edgeUV = vec2(dot(offset, sp.edgeS), dot(offset, sp.edgeT));
    return sp.o + offset;
}

// The edge-weight factor at edge coordinates uv: piecewise linear through the
// ratios at (+-1, 0) and (0, +-1), 1 at the centre.
float edgeFactor(uint edge, vec2 uv) {
    if (edge == 0u) return 1.0;
    vec4 e = unpackUnorm4x8(edge) * SC_EDGE_RATIO_MAX;
    float fs = uv.x > 0.0 ? e.x : e.y, ft = uv.y > 0.0 ? e.z : e.w;
    return clamp(1.0 + (fs - 1.0) * abs(uv.x) + (ft - 1.0) * abs(uv.y), 0.0, SC_EDGE_RATIO_MAX);
}

// Visibility pass (Ren 2002 §5.1): the splat pushed back by z_t along the ray
// through its centre. z_t scales with the splat's footprint (its longer axis),
// not r alone: under minification a pixel gathers splats from a patch whose
// depth spans about its footprint, and an offset of r keeps only the nearest
// slab (measured on the bunny, minified, per-surfel brightness error: mean
// 0.77 with r, 0.46 with sqrt(L0 L1), 0.38 with max(L0, L1)).
vec3 pushBack(Splat sp, vec3 p) { return p + frame.kernel.z * sp.footprint * normalize(sp.o); }

// Circles: a screen-aligned square of half-size r times the kernel scale
// projected (at least half a pixel) at the centre's depth; y in [-1, 1]^2.
vec4 circleCorner(vec3 o, float radius, int corner, out vec2 y) {
    float eta = frame.viewport.x;
    float rpx = max(eta * radius * frame.kernel.x / o.z, 0.5);
    y = 2.0 * vec2(corner & 1, corner >> 1) - 1.0;
    vec4 clip = project(o);
    clip.xy += vec2(y.x * 2.0 * rpx / frame.viewport.y, kYSign * y.y * 2.0 * rpx / frame.viewport.z) * o.z;
    return clip;
}
