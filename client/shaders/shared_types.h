// Structs the GPU reads, defined once for C++ and GLSL (DESIGN.md, Style).
// C++ side: static_asserts in client/render/gpu_types.h pin sizes and offsets.
#ifndef SURFCAST_SHARED_TYPES_H
#define SURFCAST_SHARED_TYPES_H

#ifdef __cplusplus
#include <cstdint>
namespace surfcast::gpu_types {
using uint = uint32_t;
struct alignas(16) vec4 { float x, y, z, w; };
#endif

// One surfel as uploaded (32 bytes, a per-instance vertex binding). Positions are
// relative to the render origin (float), the normal is octahedral-encoded as two
// snorm16 (x in the low half), the colour RGBA8 unorm.
struct GpuSurfel {
    float px, py, pz;
    float radius;    // r = h (or the surfel's own radius), world units
    uint normal;     // packSnorm2x16(octahedral(n))
    uint color;      // packUnorm4x8(rgba)
    float weight;    // per-surfel normalization weight s_k (1 when absent)
    uint edge;       // edge weights (Ren 2002 §7.2) at the tangent points +r s, -r s, +r t, -r t
                     // (s, t: tangentBasis of the world normal) as packUnorm4x8(ratio to s_k /
                     // SC_EDGE_RATIO_MAX); 0: none
};

// Per-frame parameters (push constants, 128 bytes: the guaranteed limit, so
// scalars share the clip box's w and the shading lives in `flags`).
struct FrameParams {
    vec4 view0, view1, view2;  // rows of the world->camera transform (camera: x right, y up, z forward)
    vec4 viewport;   // eta, width, height, near
    vec4 kernel;     // kernel scale (multiple of r), cutoff c, z_t (multiple of r), low-pass variance (px^2)
    // With SC_FLAG_CLIP, splats whose centre lies outside the box
    // [clipMin.xyz, clipMax.xyz] (render-origin coordinates, bounds included)
    // are not drawn, in every mode.
    vec4 clipMin;    // w: edge antialiasing's tau on sum(exp(-q/2))
    vec4 clipMax;    // w: multiplies every surfel's stored opacity (--opacity)
    uint background; // packUnorm4x8(r, g, b, 0)
    uint mode;       // SC_MODE_* below
    uint flags;      // SC_FLAG_* below
    uint layer;      // translucent frames: the layer being drawn, 0 the nearest
};

#define SC_MODE_POINTS 0u
#define SC_MODE_CIRCLES 1u
#define SC_MODE_EWA_NOPREFILTER 2u
#define SC_MODE_EWA_SURFEL 3u
#define SC_MODE_EWA_PIXEL 4u

// Largest edge-weight ratio a GpuSurfel can carry.
#define SC_EDGE_RATIO_MAX 4.0

// Splats whose (oriented) normal faces away from the eye are dropped, in every
// mode (docs/RENDERER.md, "Backface culling").
#define SC_FLAG_BACKFACE_CULL 1u
// Edge antialiasing (Zwicker 2001 §7): a pixel on the covered region's border
// has coverage min(1, sum(g) / tau) and the surface blends over the
// background by it; without the flag (and inside) a pixel shows the surface
// wherever a kernel reaches it.
#define SC_FLAG_EDGE_AA 2u
// Translucent frame (some opacity under 1): the ewa modes peel `layers`
// surfaces per pixel, each normalized on its own, and composite them front to
// back (docs/RENDERER.md, "Transparency"). Without it, opacity is ignored.
#define SC_FLAG_TRANSLUCENT 4u
// Shading in the resolve: unlit without SC_FLAG_LIT; Lambert with it (a
// headlight); Phong with SC_FLAG_SPECULAR too.
#define SC_FLAG_LIT 8u
#define SC_FLAG_SPECULAR 16u
// The clip box (FrameParams::clipMin, clipMax) applies.
#define SC_FLAG_CLIP 32u

// Clamp of the low-pass filter's object-space extent at grazing angles: at
// most this many pixels' worth at the surfel's depth (render_settings.h says why).
#define SC_MAX_FILTER_PIXELS 64.0

#ifdef __cplusplus
}  // namespace surfcast::gpu_types
#endif
#endif
