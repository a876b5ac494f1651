#version 450
// Geometry-shader expansion: the EWA setup runs once per surfel (the instanced
// quad runs it per corner) and emits the 4-vertex parallelogram.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(constant_id = 0) const int kPass = 1;

layout(points) in;
layout(triangle_strip, max_vertices = 4) out;

layout(location = 1) flat in vec3 inColor[];
layout(location = 4) flat in vec4 inPositionRadius[];
layout(location = 5) flat in uint inPackedNormal[];
layout(location = 6) flat in float inWeight[];
layout(location = 7) flat in uint inPackedEdge[];

layout(location = 0) out vec2 outY;
layout(location = 1) flat out vec3 outColor;
layout(location = 2) flat out vec3 outNormal;
layout(location = 3) flat out float outAmplitude;
layout(location = 4) out vec2 outEdgeUV;
layout(location = 5) flat out uint outEdge;
#ifdef SC_LAYERED  // translucent frames' variant (client/CMakeLists.txt)
layout(location = 8) flat in float inAlpha[];
layout(location = 6) flat out float outAlpha;
layout(location = 7) noperspective out float outDepth;  // as splat_quad.vert's
#define LAYERED(statement) statement
#else
#define LAYERED(statement)
#endif

void main() {
    Splat sp;
    if (!setupSplat(inPositionRadius[0].xyz, inPositionRadius[0].w, inPackedNormal[0], inWeight[0], inPackedEdge[0], sp))
        return;
    for (int corner = 0; corner < 4; ++corner) {
        vec2 y, edgeUV;
        vec3 p = splatCorner(sp, corner, y, edgeUV);
        LAYERED(outDepth = frame.viewport.w / p.z);
        if (kPass == 0) p = pushBack(sp, p);
        gl_Position = project(p);
        outY = y;
        outColor = inColor[0];
        outNormal = sp.n;
        outAmplitude = sp.amplitude;
        outEdgeUV = edgeUV;
        outEdge = sp.edge;
        LAYERED(outAlpha = inAlpha[0]);
        EmitVertex();
    }
    EndPrimitive();
}
