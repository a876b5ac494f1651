// The surfel a vertex belongs to, and which corner of its splat the vertex is.
// Vulkan: one instance per surfel (a per-instance vertex binding of GpuSurfel),
// gl_VertexIndex its triangle strip's corner. GLSL ES (the browser): surfels
// are pulled from an RGBA32UI texture, two texels each, 1024 to a row, by
// gl_VertexID, SC_SURFEL_VERTICES vertices each (six: two triangles; instanced
// attributes cost SwiftShader 16 times as much: docs/WEB.md, "Differences
// from the Vulkan client"). Call loadSurfel() first in main.
#ifdef SC_GLSL_ES
uniform highp usampler2D scSurfels;
vec4 inPositionRadius;
uint inNormal;
vec4 inColor;
float inWeight;
uint inEdge;
void loadSurfel() {
    int id = gl_VertexID / SC_SURFEL_VERTICES;
    ivec2 at = ivec2((id & 1023) * 2, id >> 10);
    uvec4 t0 = texelFetch(scSurfels, at, 0), t1 = texelFetch(scSurfels, at + ivec2(1, 0), 0);
    inPositionRadius = uintBitsToFloat(t0);
    inNormal = t1.x;
    inColor = vec4(uvec4(t1.y, t1.y >> 8, t1.y >> 16, t1.y >> 24) & 255u) / 255.0;
    inWeight = uintBitsToFloat(t1.z);
    inEdge = t1.w;
}
// The strip corners 0 1 2 3 as two triangles.
const int kStripCorners[6] = int[6](0, 1, 2, 2, 1, 3);
int cornerIndex() { return kStripCorners[gl_VertexID % SC_SURFEL_VERTICES]; }
// The surfel's index in its node's texture.
uint surfelIndex() { return uint(gl_VertexID / SC_SURFEL_VERTICES); }
#else
layout(location = 0) in vec4 inPositionRadius;
layout(location = 1) in uint inNormal;
layout(location = 2) in vec4 inColor;
layout(location = 3) in float inWeight;
layout(location = 4) in uint inEdge;
void loadSurfel() {}
int cornerIndex() { return gl_VertexIndex; }
// The surfel's index in the vertex buffer.
uint surfelIndex() { return uint(gl_InstanceIndex); }
#endif
