// The CPU reference: screen-space EWA surface splatting after Zwicker et al.
// 2001, §3-4 (`../shared/papers/surface-splatting-zwicker2001.md`). No Vulkan;
// deterministic (the result does not depend on the thread count); the GPU
// renderer is tested against it.
#pragma once

#include "camera.h"
#include "image.h"
#include "render_settings.h"
#include "surfel_set.h"

namespace surfcast {

struct CpuFrameStats {
    size_t splats = 0;          // surfels that reached the rasterizer
    size_t pixelsCovered = 0;
    double milliseconds = 0;
};

// Renders with per-pixel normalization (eq. 9), V^h = settings.lowpassVariance
// * I and the two-pass z-threshold visibility the GPU uses (each pixel keeps
// the fragments within z_t of its nearest surface). Translucent frames
// (settings.translucent, or opacity under 1) keep the paper's A-buffer
// instead (§6: up to settings.layers fragments per pixel, blended by eq. 12;
// docs/RENDERER.md, "Transparency"). settings.mode is ignored.
Image renderCpuReference(const SurfelSet& set, const ViewTransform& view, const RenderSettings& settings,
                         CpuFrameStats* stats = nullptr);

// The near plane both renderers use: kNearFraction of the larger of the set's
// diagonal and the eye's distance to the set's centre (a set of one point has
// no diagonal; depth = near / z must stay well above zero where drawn).
float nearPlaneFor(double diagonal, const ViewTransform& view);
double diagonalOf(const SurfelSet& set);

}  // namespace surfcast
