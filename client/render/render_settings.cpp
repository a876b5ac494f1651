#include "render_settings.h"

#include <algorithm>
#include <cmath>

namespace surfcast {

namespace {
struct ModeName {
    RenderMode mode;
    const char* name;
};
constexpr ModeName kModes[] = {
    {RenderMode::Points, "points"},          {RenderMode::Circles, "circles"},
    {RenderMode::EwaNoPrefilter, "ewa-noprefilter"}, {RenderMode::EwaSurfel, "ewa-surfel"},
    {RenderMode::EwaPixel, "ewa-pixel"},     {RenderMode::CpuReference, "cpu-reference"},
};
// Headlight shading: ambient + diffuse (+ a Blinn-Phong highlight).
constexpr float kAmbient = 0.25f, kDiffuse = 0.75f, kSpecular = 0.3f, kShininess = 32.f;
}  // namespace

std::optional<RenderMode> parseRenderMode(const std::string& name) {
    for (const auto& m : kModes)
        if (name == m.name) return m.mode;
    return std::nullopt;
}

const char* renderModeName(RenderMode mode) {
    for (const auto& m : kModes)
        if (m.mode == mode) return m.name;
    return "?";
}

std::optional<Shading> parseShading(const std::string& name) {
    if (name == "unlit") return Shading::Unlit;
    if (name == "lambert") return Shading::Lambert;
    if (name == "phong") return Shading::Phong;
    return std::nullopt;
}

gpu_types::FrameParams makeFrameParams(const ViewTransform& view, const RenderSettings& s, float nearPlane) {
    gpu_types::FrameParams p{};
    p.view0 = {view.rows[0][0], view.rows[0][1], view.rows[0][2], view.rows[0][3]};
    p.view1 = {view.rows[1][0], view.rows[1][1], view.rows[1][2], view.rows[1][3]};
    p.view2 = {view.rows[2][0], view.rows[2][1], view.rows[2][2], view.rows[2][3]};
    p.viewport = {view.eta, float(view.width), float(view.height), nearPlane};
    float lowpass = s.mode == RenderMode::EwaNoPrefilter ? 0.f : s.lowpassVariance;
    p.kernel = {s.kernelScale, s.cutoff, s.zt, lowpass};
    const std::optional<LocalClip> clip = localClip(s, view.origin);
    p.clipMin = {clip ? clip->min.x : 0.f, clip ? clip->min.y : 0.f, clip ? clip->min.z : 0.f, s.edgeTau};
    p.clipMax = {clip ? clip->max.x : 0.f, clip ? clip->max.y : 0.f, clip ? clip->max.z : 0.f,
                 std::clamp(s.opacity, 0.f, 1.f)};
    auto unorm8 = [](float v) { return uint32_t(std::lround(std::clamp(v, 0.f, 1.f) * 255.f)); };
    p.background = unorm8(s.background.x) | unorm8(s.background.y) << 8 | unorm8(s.background.z) << 16;
    switch (s.mode) {
    case RenderMode::Points: p.mode = SC_MODE_POINTS; break;
    case RenderMode::Circles: p.mode = SC_MODE_CIRCLES; break;
    case RenderMode::EwaNoPrefilter: p.mode = SC_MODE_EWA_NOPREFILTER; break;
    case RenderMode::EwaSurfel: p.mode = SC_MODE_EWA_SURFEL; break;
    case RenderMode::EwaPixel:
    case RenderMode::CpuReference: p.mode = SC_MODE_EWA_PIXEL; break;
    }
    p.flags = (s.backfaceCull ? SC_FLAG_BACKFACE_CULL : 0u) | (s.edgeAA ? SC_FLAG_EDGE_AA : 0u) |
              (translucentFrame(s) ? SC_FLAG_TRANSLUCENT : 0u) | (s.shading != Shading::Unlit ? SC_FLAG_LIT : 0u) |
              (s.shading == Shading::Phong ? SC_FLAG_SPECULAR : 0u) | (clip ? SC_FLAG_CLIP : 0u);
    p.layer = 0;
    return p;
}

std::optional<LocalClip> localClip(const RenderSettings& s, const Vec3d& origin) {
    if (!s.clip) return std::nullopt;
    return LocalClip{cast<float>(s.clip->min - origin), cast<float>(s.clip->max - origin)};
}

Vec3f shadePixel(Shading shading, const Vec3f& color, const Vec3f& normal, const Vec3f& ray) {
    if (shading == Shading::Unlit) return color;
    Vec3f n = normalizeOrZero(normal);
    Vec3f v = normalizeOrZero(ray) * -1.f;  // toward the eye; the light sits at the eye
    float ndotv = std::fabs(dot(n, v));     // splats are two-sided
    float light = kAmbient + kDiffuse * ndotv;
    Vec3f out = color * light;
    if (shading == Shading::Phong) {
        float spec = kSpecular * std::pow(ndotv, kShininess);  // half vector = v for a headlight
        out = out + Vec3f{spec, spec, spec};
    }
    return {std::fmin(out.x, 1.f), std::fmin(out.y, 1.f), std::fmin(out.z, 1.f)};
}

RenderSettings settingsForSet(double kernelScale, bool hasColor, bool oriented, bool translucent) {
    RenderSettings s;
    s.translucent = translucent;
    s.kernelScale = float(kernelScale);
    s.shading = hasColor ? Shading::Unlit : Shading::Lambert;
    s.backfaceCull = oriented;
    s.edgeAA = true;
    return s;
}

}  // namespace surfcast
