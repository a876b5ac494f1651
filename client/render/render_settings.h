// What a frame is drawn with: the renderer mode (each a point on the
// speed-accuracy chart), the EWA parameters and the resolve's shading. Shared
// by the GPU renderer and the CPU reference.
#pragma once

#include <optional>
#include <string>

#include "camera.h"
#include "gpu_types.h"
#include "tileset_format.h"
#include "vec3.h"

namespace surfcast {

enum class RenderMode {
    Points,          // 1-px points, nearest wins
    Circles,         // opaque screen-facing discs of radius r (as Potree draws)
    EwaNoPrefilter,  // object-space EWA, reconstruction kernel only, per-pixel normalization
    EwaSurfel,       // object-space EWA, per-surfel weights s_k, no division
    EwaPixel,        // object-space EWA, per-pixel normalization (the default)
    CpuReference,    // screen-space EWA on the CPU (Zwicker 2001)
};
enum class Shading { Unlit, Lambert, Phong };

std::optional<RenderMode> parseRenderMode(const std::string& name);
const char* renderModeName(RenderMode mode);
std::optional<Shading> parseShading(const std::string& name);

// The defaults' values come from common/render_defaults.json (the filter
// clamp from shared_types.h), which the browser reads too; why each has its
// value is said here.
// Clamp of the low-pass filter's object-space extent where J is near singular
// (grazing angles): at most this many pixels' worth at the surfel's depth.
inline constexpr float kMaxFilterPixels = float(SC_MAX_FILTER_PIXELS);  // shared_types.h: the shaders read it too
// Default low-pass filter V^h = v I (pixels^2). Zwicker 2001 uses V^h = I; a
// supersampled pixel's box filter has variance 1/12. Measured by
// bench/accuracy_bench.py (mean FLIP, ewa-pixel): v = 0.1 is best on the
// checkerboard receding to the horizon, the aliasing case (0.166 against
// 0.197 at v = 1 and 0.185 without a filter), and ties with no filter on
// average (0.137 against 0.135; smooth meshes sampled below a pixel prefer
// none); v = 1 darkens and widens every silhouette by about a pixel.
inline constexpr float kDefaultLowpassVariance = defaults::kLowpassVariance;
// Default tau of edge antialiasing, in sums of exp(-y'y/2) (a covered pixel
// sums at least exp(-c) = 0.37). Measured by bench/edge_aa_bench.py on the
// meshes' silhouettes (FLIP over silhouette pixels, against 0.30-0.32
// without edge AA): 0.28-0.30 at 0.75, 0.15-0.18 at 3, 0.13-0.16 at 4, and
// worse again at 8. Interiors never change: only border pixels take partial
// coverage.
inline constexpr float kDefaultEdgeTau = defaults::kEdgeTau;
// Default l, the fragment layers per pixel of translucent frames (Zwicker 2001
// §6): each costs one visibility and one accumulation pass over the splats.
// Measured by bench/transparency_bench.py: every scene's FLIP stops falling
// at l = 3 (crossing planes 0.247 at 1, 0.074 from 2; a translucent sphere
// over a floor 0.222, 0.168, 0.151 from 3; three stacked layers 0.182, 0.101,
// 0.063 from 3), while l = 4 takes 35-48 % longer than 3.
inline constexpr int kDefaultLayers = defaults::kLayers;
inline constexpr int kMaxLayers = defaults::kMaxLayers;
// Near plane, as a fraction of the larger of the set's bounding-box diagonal
// and the eye's distance to its centre (nearPlaneFor; reversed-Z depth keeps
// float precision at every distance, so it can be small).
inline constexpr double kNearFraction = defaults::kNearFraction;

struct RenderSettings {
    RenderMode mode = RenderMode::EwaPixel;
    Shading shading = Shading::Unlit;
    float kernelScale = float(kDefaultKernelScale);  // V^r = (kernelScale * r)^2 I; a set's weights
                                                    // assume its tileset.json kernel_scale
    float cutoff = 1.f;           // c: splats end at y'y = 2c
    float zt = float(kDefaultZt);  // visibility depth offset z_t, a multiple of the footprint (k r magnified)
    float lowpassVariance = kDefaultLowpassVariance;  // V^h = variance * I, in pixels^2
    // Edge antialiasing (Zwicker 2001 §7): on the covered region's border
    // (a pixel with an uncovered 4-neighbour), coverage min(1, sum / tau) of
    // the unscaled kernels exp(-y'y/2) blends the surface over the
    // background. Off (and inside): the surface shows wherever a kernel
    // reaches (kernels end at exp(-c), so no covered pixel sums less).
    bool edgeAA = false;
    float edgeTau = kDefaultEdgeTau;
    Vec3f background{1.f, 1.f, 1.f};
    // Drop splats whose normal faces away from the eye (every mode): right
    // where normals are oriented (normalsOriented below), wrong where their
    // sign is arbitrary.
    bool backfaceCull = false;
    // Transparency (Zwicker 2001 §6): a frame is translucent where the set
    // stores opacity (SurfelSet::translucent) or `opacity` is under 1, which
    // multiplies every surfel's. Translucent frames resolve up to `layers`
    // surfaces per pixel and blend them by eq. 12 (the GPU front to back, each
    // layer under the nearer ones; the CPU reference back to front); past that,
    // surfaces merge (on the GPU the last layer takes all the rest, in the
    // CPU reference the two closest in depth merge, as in the paper). Points
    // and circles stay opaque.
    bool translucent = false;
    float opacity = 1.f;
    int layers = kDefaultLayers;
    // A clip box in world coordinates: only splats whose centre lies inside
    // (bounds included) are drawn, in every mode. Tested in float relative to
    // the render origin (localClip), by the GPU and the CPU reference alike.
    std::optional<Box3d> clip;
};

// The clip box relative to a render origin, in float, as the shaders test it.
struct LocalClip {
    Vec3f min, max;
    bool contains(const Vec3f& p) const {
        return p.x >= min.x && p.y >= min.y && p.z >= min.z && p.x <= max.x && p.y <= max.y && p.z <= max.z;
    }
};
std::optional<LocalClip> localClip(const RenderSettings& settings, const Vec3d& origin);

// Whether a frame with these settings is translucent (RenderSettings::translucent).
inline bool translucentFrame(const RenderSettings& s) { return s.translucent || s.opacity < 1.f; }

// Push constants for one frame; `nearPlane` in world units, the clip box
// relative to `view.origin`.
gpu_types::FrameParams makeFrameParams(const ViewTransform& view, const RenderSettings& settings, float nearPlane);

// The settings a tile set is drawn with unless told otherwise: the kernel
// scale its weights assume (tileset.json kernel_scale), unlit when it has
// colours, else Lambert; backface culling where its normals are oriented;
// edge antialiasing on; translucent where the set stores opacity.
RenderSettings settingsForSet(double kernelScale, bool hasColor, bool oriented, bool translucent = false);

// The resolve's shading of one pixel (the GLSL resolve shader is its twin):
// colour, filtered camera-space normal (any length), pixel ray direction.
Vec3f shadePixel(Shading shading, const Vec3f& color, const Vec3f& normal, const Vec3f& ray);

}  // namespace surfcast
