// GLSL ES 3.00 twins of client/shaders: the object-space EWA setup of Ren et
// al. 2002, §5.2 (splat_common.glsl), the visibility and accumulation passes,
// points and circles, the resolve (resolve.frag, resolve_common.glsl), and
// the translucent frames' depth peeling (splat_peel.frag, splat_layer.frag,
// resolve_layer.frag, composite.frag).
// Differences from the Vulkan shaders, all of convention: uniforms instead of
// push constants; surfels pulled from a texture by gl_VertexID, six vertices
// (two triangles) a splat; OpenGL's clip space (y up, and depth near/z reached through
// z_clip = 2 near - z where EXT_clip_control is missing); gl_FragCoord's
// origin at the bottom left.

export const kModePoints = 0, kModeCircles = 1, kModeEwaNoPrefilter = 2, kModeEwaSurfel = 3, kModeEwaPixel = 4;
export const kFlagBackfaceCull = 1, kFlagEdgeAA = 2;
export const kShadingUnlit = 0, kShadingLambert = 1, kShadingPhong = 2;
export const kPassVisibility = 0, kPassAccumulate = 1, kPassCircles = 2, kPassPoints = 3;

const common = `
uniform vec4 uView0, uView1, uView2;
uniform vec4 uViewport;   // eta, width, height, near
uniform vec4 uKernel;     // kernel scale, cutoff c, z_t, low-pass variance (px^2)
uniform vec4 uResolve;    // background rgb, edge AA tau
uniform uint uMode, uShading, uFlags;
uniform float uMaxFilterPixels, uCircleScale;
uniform bool uClipControl; // depth in [0, 1] straight from clip z (EXT_clip_control)
uniform float uOpacity;    // multiplies every surfel's stored opacity
uniform uint uLayer;       // translucent frames: the layer being drawn, 0 the nearest
const float kEdgeRatioMax = 4.0;
`;

const edgeFactorSource = `
float edgeFactor(uint edge, vec2 uv) {
  if (edge == 0u) return 1.0;
  vec4 e = vec4(float(edge & 255u), float((edge >> 8) & 255u), float((edge >> 16) & 255u), float(edge >> 24)) / 255.0 * kEdgeRatioMax;
  float fs = uv.x > 0.0 ? e.x : e.y, ft = uv.y > 0.0 ? e.z : e.w;
  return clamp(1.0 + (fs - 1.0) * abs(uv.x) + (ft - 1.0) * abs(uv.y), 0.0, kEdgeRatioMax);
}
`;

// Edge antialiasing's coverage and the deferred shading (resolve_common.glsl).
const resolveCommon = `
const float kAmbient = 0.25, kDiffuse = 0.75, kSpecular = 0.3, kShininess = 32.0;
float edgeCoverage(ivec2 pixel, float g) {
  if ((uFlags & 2u) == 0u || !(g < uResolve.a)) return 1.0;
  ivec2 last = textureSize(uNormalWeight, 0) - 1;
  bool border = false;
  for (int k = 0; k < 4; ++k) {
    ivec2 q = clamp(pixel + ivec2(k == 0 ? 1 : k == 1 ? -1 : 0, k == 2 ? 1 : k == 3 ? -1 : 0), ivec2(0), last);
    border = border || !(texelFetch(uNormalWeight, q, 0).a > 0.0);
  }
  return border ? g / uResolve.a : 1.0;
}
vec3 shade(vec3 color, vec3 normalSum) {
  if (uShading == 0u) return color;
  float eta = uViewport.x;
  vec3 ray = vec3((gl_FragCoord.x - 0.5 * uViewport.y) / eta, (gl_FragCoord.y - 0.5 * uViewport.z) / eta, 1.0);
  vec3 n = dot(normalSum, normalSum) > 0.0 ? normalize(normalSum) : vec3(0);
  float ndotv = abs(dot(n, -normalize(ray)));
  vec3 lit = color * (kAmbient + kDiffuse * ndotv);
  if (uShading == 2u) lit += vec3(kSpecular * pow(ndotv, kShininess));
  return min(lit, vec3(1.0));
}
`;

// `layered`: the translucent frames' variant, which also passes on the
// opacity and the splat's own depth (near / z, not pushed back), interpolated
// linearly in screen space as the Vulkan shaders' noperspective varying is:
// GLSL ES has no noperspective, so it goes as depth * w and w, both
// perspective-correct, whose ratio is exactly the screen-linear depth.
export const splatVertex = (pass: number, layered = false) => `#version 300 es
precision highp float;
precision highp int;
${common}
// The node's surfels, two RGBA32UI texels each (the GpuSurfel layout), 1024
// to a row, read by gl_VertexID (vertex pulling): instanced attributes cost
// SwiftShader about 16 times as much (an ewa-pixel frame of 535,000 splats at
// 640x480: 15.8 s instanced, 0.97 s pulled; points 3.4 s against 0.10 s).
uniform highp usampler2D uSurfels;
out vec2 vY;
flat out vec3 vColor;
flat out vec3 vNormal;
flat out float vAmplitude;
out vec2 vEdgeUV;
flat out uint vEdge;
#define LAYERED ${layered ? 1 : 0}
#if LAYERED
flat out float vAlpha;
out float vDepthW, vW;
#endif

vec3 toCamera(vec3 p) {
  vec4 q = vec4(p, 1.0);
  return vec3(dot(uView0, q), dot(uView1, q), dot(uView2, q));
}
vec3 rotateToCamera(vec3 v) { return vec3(dot(uView0.xyz, v), dot(uView1.xyz, v), dot(uView2.xyz, v)); }
// Reversed Z, infinite far plane: depth = near / z.
vec4 project(vec3 c) {
  float eta = uViewport.x, near = uViewport.w;
  return vec4(2.0 * eta / uViewport.y * c.x, 2.0 * eta / uViewport.z * c.y, uClipControl ? near : 2.0 * near - c.z, c.z);
}
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
bool culledAsBackface(vec3 n, vec3 o) { return (uFlags & 1u) != 0u && dot(n, o) > 0.0; }
float splatRadius(float r, float z) { return r > 0.0 && !isinf(r) ? r : z / uViewport.x; }
vec3 tangentOf(vec3 n) {
  vec3 a = abs(n.x) < 0.9 ? vec3(1, 0, 0) : vec3(0, 1, 0);
  return normalize(cross(n, a));
}

const int kCorners[6] = int[6](0, 1, 2, 2, 1, 3);  // two triangles of the strip's four corners

void main() {
#if ${pass} == 3
  int id = gl_VertexID, corner = 0;
#else
  int id = gl_VertexID / 6, corner = kCorners[gl_VertexID - 6 * id];
#endif
  ivec2 at = ivec2((id & 1023) * 2, id >> 10);
  uvec4 t0 = texelFetch(uSurfels, at, 0), t1 = texelFetch(uSurfels, at + ivec2(1, 0), 0);
  vec4 inPositionRadius = uintBitsToFloat(t0);
  uint inNormal = t1.x, inEdge = t1.w;
  vec4 inColor = vec4(uvec4(t1.y, t1.y >> 8, t1.y >> 16, t1.y >> 24) & 255u) / 255.0;
  float inWeight = uintBitsToFloat(t1.z);
  vColor = inColor.rgb;
  vY = vec2(0);
  vEdgeUV = vec2(0);
  vEdge = 0u;
  vAmplitude = 1.0;
#if LAYERED
  vAlpha = inColor.a * uOpacity;
  vDepthW = 0.0;
  vW = 1.0;
#endif
  vec3 o = toCamera(inPositionRadius.xyz);
  vec3 nw = decodeNormal(inNormal);
  vec3 n = rotateToCamera(nw);
  bool ok = finite3(o) && o.z >= uViewport.w && finite3(n) && !culledAsBackface(n, o);
  n = dot(n, o) > 0.0 ? -n : n;
  vNormal = n;
#if ${pass} == 3
  gl_PointSize = 1.0;
  gl_Position = ok ? project(o) : kCulled;
#elif ${pass} == 2
  float eta = uViewport.x;
  float rpx = max(eta * splatRadius(inPositionRadius.w, o.z) * uCircleScale / o.z, 0.5);
  vec2 y = 2.0 * vec2(corner & 1, corner >> 1) - 1.0;
  vY = y;
  vec4 clip = project(o);
  clip.xy += vec2(y.x * 2.0 * rpx / uViewport.y, y.y * 2.0 * rpx / uViewport.z) * o.z;
  gl_Position = ok ? clip : kCulled;
#else
  if (!ok) {
    gl_Position = kCulled;
    return;
  }
  // Object-space EWA (Ren 2002 §5.2): J's columns at the centre, M = V^r +
  // V^h J^-1 J^-T from J'J's eigensystem, the singular case clamped.
  float eta = uViewport.x;
  vec3 s = tangentOf(n), t = cross(n, s);
  float r = splatRadius(inPositionRadius.w * uKernel.x, o.z);
  float k = eta / (o.z * o.z);
  vec2 js = k * vec2(s.x * o.z - s.z * o.x, s.y * o.z - s.z * o.y);
  vec2 jt = k * vec2(t.x * o.z - t.z * o.x, t.y * o.z - t.z * o.y);
  float a = dot(js, js), b = dot(js, jt), c = dot(jt, jt);
  float mean = 0.5 * (a + c), dev = sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0));
  float l0 = mean + dev, l1 = max(mean - dev, 0.0);
  vec2 e0 = a >= c ? vec2(l0 - c, b) : vec2(b, l0 - a);
  e0 = dot(e0, e0) > 0.0 ? normalize(e0) : vec2(1, 0);
  vec2 e1 = vec2(-e0.y, e0.x);
  float lmin = eta / (uMaxFilterPixels * o.z);
  lmin *= lmin;
  float lowpass = uKernel.w;
  float L0 = sqrt(r * r + lowpass / max(l0, lmin)), L1 = sqrt(r * r + lowpass / max(l1, lmin));
  vec3 axisU = L0 * (e0.x * s + e0.y * t), axisV = L1 * (e1.x * s + e1.y * t);
  float amplitude = r * r / (L0 * L1) * (uMode == ${kModeEwaSurfel}u ? inWeight : 1.0);
  if (!finite3(axisU) || !finite3(axisV) || isnan(amplitude) || isinf(amplitude)) {
    gl_Position = kCulled;
    return;
  }
  vec2 v = vec2(corner & 1, corner >> 1);
  vec2 y = 2.0 * sqrt(2.0 * uKernel.y) * (v - 0.5);
  vec3 offset = y.x * axisU + y.y * axisV;
  vY = y;
  vAmplitude = amplitude;
  if (uMode == ${kModeEwaSurfel}u && inEdge != 0u) {
    vec3 sw = tangentOf(nw);
    vEdgeUV = vec2(dot(offset, rotateToCamera(sw) / r), dot(offset, rotateToCamera(cross(nw, sw)) / r));
    vEdge = inEdge;
  }
  vec3 p = o + offset;
  float ownDepth = uViewport.w / p.z;
#if ${pass} == 0
  // Visibility: pushed back by z_t times the footprint along the centre's ray.
  p += uKernel.z * max(L0, L1) * normalize(o);
#endif
  gl_Position = project(p);
#if LAYERED
  vDepthW = ownDepth * gl_Position.w;
  vW = gl_Position.w;
#endif
#endif
}
`;

export const visibilityFragment = `#version 300 es
precision highp float;
${common}
in vec2 vY;
void main() {
  if (dot(vY, vY) > 2.0 * uKernel.y) discard;
}
`;

// The accumulation pass (splat_accumulate.frag); `layered`: of one layer of
// a translucent frame (splat_layer.frag), without the layers in front (at or
// nearer than layer k-1's pushed-back surface), plus the opacity's weighted sum.
// `unsigned8`: the targets are RGBA8 (no float blending), which clamp
// negative sums, so the normal is accumulated as (n + 1) / 2 · w and the
// resolve takes 2 Σ(...) - Σw.
export const accumulateFragment = (layered: boolean, unsigned8 = false) => `#version 300 es
precision highp float;
precision highp int;
${common}
in vec2 vY;
flat in vec3 vColor;
flat in vec3 vNormal;
flat in float vAmplitude;
in vec2 vEdgeUV;
flat in uint vEdge;
layout(location = 0) out vec4 outColorWeight;
layout(location = 1) out vec4 outNormalWeight;
#if ${layered ? 1 : 0}
uniform highp sampler2D uPreviousDepth;
flat in float vAlpha;
layout(location = 2) out vec4 outAlphaWeight;
#endif
${edgeFactorSource}
void main() {
  float q = dot(vY, vY);
  if (q > 2.0 * uKernel.y) discard;
#if ${layered ? 1 : 0}
  if (uLayer > 0u && gl_FragCoord.z >= texelFetch(uPreviousDepth, ivec2(gl_FragCoord.xy), 0).r) discard;
#endif
  float g = exp(-0.5 * q);
  float w = vAmplitude * g * edgeFactor(vEdge, vEdgeUV);
  outColorWeight = vec4(vColor * w, w);
#if ${unsigned8 ? 1 : 0}
  outNormalWeight = vec4((0.5 * vNormal + 0.5) * w, g);
#else
  outNormalWeight = vec4(vNormal * w, g);
#endif
#if ${layered ? 1 : 0}
  outAlphaWeight = vec4(vAlpha * w, 0.0, 0.0, 0.0);
#endif
}
`;

export const opaqueFragment = (circle: boolean) => `#version 300 es
precision highp float;
${common}
in vec2 vY;
flat in vec3 vColor;
flat in vec3 vNormal;
layout(location = 0) out vec4 outColorWeight;
layout(location = 1) out vec4 outNormalWeight;
void main() {
  ${circle ? "if (dot(vY, vY) > 1.0) discard;" : ""}
  outColorWeight = vec4(vColor, 1.0);
  outNormalWeight = vec4(vNormal, 1.0);
}
`;

// The accumulated targets the resolves read.
const resolveHead = `precision highp float;
precision highp int;
${common}
uniform highp sampler2D uColorWeight;
uniform highp sampler2D uNormalWeight;
`;

export const resolveVertex = `#version 300 es
void main() {
  vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
`;

// `unsigned8`: the normal was accumulated as accumulateFragment's unsigned8 writes it.
export const resolveFragment = (unsigned8 = false) => `#version 300 es
${resolveHead}out vec4 outColor;
${resolveCommon}
void main() {
  ivec2 pixel = ivec2(gl_FragCoord.xy);
  vec4 cw = texelFetch(uColorWeight, pixel, 0);
  vec4 nw = texelFetch(uNormalWeight, pixel, 0);
  vec3 background = uResolve.rgb;
  if (!(nw.a > 0.0) || !(cw.a > 0.0)) {
    outColor = vec4(background, 1.0);
    return;
  }
  float coverage = edgeCoverage(pixel, nw.a);
  vec3 color = uMode == ${kModeEwaSurfel}u ? cw.rgb + max(1.0 - cw.a, 0.0) * background : cw.rgb / cw.a;
#if ${unsigned8 ? 1 : 0}
  color = shade(color, 2.0 * nw.xyz - cw.a);
#else
  color = shade(color, nw.xyz);
#endif
  outColor = vec4(mix(background, color, coverage), 1.0);
}
`;

// Translucent frames (Zwicker 2001 §6, depth peeling; the twins of
// splat_peel.frag, splat_layer.frag, resolve_layer.frag and composite.frag).
// The visibility pass of layer k > 0: fragments at or in front of layer
// k-1's pushed-back surface belong to the layers already drawn.
export const peelFragment = `#version 300 es
precision highp float;
${common}
uniform highp sampler2D uPreviousDepth;
in vec2 vY;
in float vDepthW, vW;
void main() {
  if (dot(vY, vY) > 2.0 * uKernel.y) discard;
  if (vDepthW / vW >= texelFetch(uPreviousDepth, ivec2(gl_FragCoord.xy), 0).r) discard;
}
`;


// After each layer's accumulation: the layer normalized and shaded, with
// opacity sum(alpha w) / sum(w) times the edge coverage, premultiplied, and
// blended under the layers in front (dst += (1 - dst.a) src: eq. 12 front to back).
export const resolveLayerFragment = `#version 300 es
${resolveHead}uniform highp sampler2D uAlphaWeight;
out vec4 outColor;
${resolveCommon}
void main() {
  ivec2 pixel = ivec2(gl_FragCoord.xy);
  vec4 cw = texelFetch(uColorWeight, pixel, 0);
  vec4 nw = texelFetch(uNormalWeight, pixel, 0);
  if (!(nw.a > 0.0) || !(cw.a > 0.0)) discard;
  vec3 color = shade(cw.rgb / cw.a, nw.xyz);
  float alpha = clamp(texelFetch(uAlphaWeight, pixel, 0).r / cw.a, 0.0, 1.0) * edgeCoverage(pixel, nw.a);
  outColor = vec4(color * alpha, alpha);
}
`;

// Last: the layers' premultiplied composite over the background.
export const compositeFragment = `#version 300 es
precision highp float;
precision highp int;
${common}
uniform highp sampler2D uComposite;
out vec4 outColor;
void main() {
  vec4 c = texelFetch(uComposite, ivec2(gl_FragCoord.xy), 0);
  outColor = vec4(c.rgb + (1.0 - c.a) * uResolve.rgb, 1.0);
}
`;
