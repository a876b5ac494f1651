// The GPU renderer: object-space EWA surface splatting after Ren et al. 2002
// (§5: visibility pass, EWA accumulation pass, normalization) plus the 1-px
// point and fixed-circle modes, all on Vulkan (client/gpu/). One frame:
//
//   points/circles: opaque draw (depth write) ──────────────┐
//   ewa-*: visibility (depth only, pushed back by z_t)      ├─► resolve ─► RGBA8 output
//          accumulation (additive, depth test, no write) ───┘   (normalize, shade)
//
// Accumulation targets: RGBA32F (colour*w, w) and (normal*w); RGBA16F on request.
//
// Translucent frames (SC_FLAG_TRANSLUCENT, ewa modes; Zwicker 2001 §6 by depth
// peeling), for each layer k < l, nearest first:
//
//   visibility k: the nearest surface behind layer k-1's pushed-back depth ─┐
//   accumulation k: its fragments, plus (alpha*w) into a third target ──────┼─► resolve layer k, blended
//                   (the last layer: every fragment left, merged)          ─┘   under layers < k
//   then the composite over the background ─► RGBA8 output
//
// Two depth images alternate: one is written while the other, layer k-1's, is
// sampled. Opaque frames never touch the translucent targets.
#pragma once

#include <memory>
#include <vector>

#include "../gpu/resources.h"
#include "camera.h"
#include "cpu_reference.h"
#include "image.h"
#include "render_settings.h"
#include "surfel_set.h"

namespace surfcast {

// How a splat becomes a quad: an instanced 4-vertex strip (setup per corner),
// or a geometry shader on points (setup once per surfel). Auto: the geometry
// shader where the device has one; it won on lavapipe by 15-40% (see
// bench/BENCHMARKS.md, "Renderer").
enum class Expansion { Auto, Quad, Geometry };

struct RendererOptions {
    Expansion expansion = Expansion::Auto;
    bool halfFloatAccumulation = false;  // RGBA16F instead of RGBA32F
};

// Surfels [first, first + count) of a vertex buffer of GpuSurfels.
struct DrawRange {
    uint32_t first = 0, count = 0;
};

struct GpuFrameStats {
    double visibilityMs = 0, accumulateMs = 0, resolveMs = 0, totalMs = 0;  // GPU timestamps
    size_t splats = 0;
    size_t pixelsCovered = 0;
};

class SplatRenderer {
public:
    static Result<std::unique_ptr<SplatRenderer>> create(gpu::Context& ctx, const RendererOptions& options);
    ~SplatRenderer();
    SplatRenderer(const SplatRenderer&) = delete;
    SplatRenderer& operator=(const SplatRenderer&) = delete;

    // Replaces the surfels drawn (device-local copy through a staging buffer).
    Status upload(const SurfelSet& set);
    // Or draws ranges of a buffer the caller owns (a SurfelPool) and keeps
    // alive while frames use it; `diagonal` of the scene sets the near plane.
    void setDraws(VkBuffer buffer, std::vector<DrawRange> ranges, double diagonal);
    Status resize(uint32_t width, uint32_t height);
    float nearPlane(const ViewTransform& view) const { return nearPlaneFor(diagonal_, view); }
    size_t splatCount() const { return splatCount_; }
    Expansion expansion() const { return options_.expansion; }

    // Records one frame; output() ends in TRANSFER_SRC_OPTIMAL, ready to copy
    // or blit.
    void record(VkCommandBuffer cmd, const ViewTransform& view, const RenderSettings& settings);
    // Per-pass GPU times of the last recorded frame, once it has completed.
    GpuFrameStats timings() const;
    const gpu::Image& output() const { return output_; }

    // Headless: record, submit, wait and read the output back.
    Result<Image> render(const ViewTransform& view, const RenderSettings& settings, GpuFrameStats* stats = nullptr);

    // Normalization-weight capture (Ren 2002 §7.2): renders ewa-noprefilter
    // (amplitude 1, no s_k) and reads back, per pixel, row-major from the top
    // left, the accumulated sum of weights and the visibility pass's depth
    // (reversed Z: near / z_pushed_back; 0 where nothing was drawn).
    Status capture(const ViewTransform& view, const RenderSettings& settings, std::vector<float>* weightSums,
                   std::vector<float>* depth);

private:
    explicit SplatRenderer(gpu::Context& ctx) : ctx_(ctx) {}
    Status createPipelines();
    void destroyTargets();

    gpu::Context& ctx_;
    RendererOptions options_;
    VkFormat accumFormat_ = VK_FORMAT_R32G32B32A32_SFLOAT;
    // The translucent layers' sum of alpha*w, as wide as the other targets.
    VkFormat alphaFormat() const {
        return accumFormat_ == VK_FORMAT_R32G32B32A32_SFLOAT ? VK_FORMAT_R32_SFLOAT : VK_FORMAT_R16_SFLOAT;
    }
    VkDescriptorSetLayout resolveSetLayout_ = VK_NULL_HANDLE;
    VkDescriptorPool descriptorPool_ = VK_NULL_HANDLE;
    VkDescriptorSet resolveSet_ = VK_NULL_HANDLE;
    VkSampler sampler_ = VK_NULL_HANDLE;
    VkPipelineLayout splatLayout_ = VK_NULL_HANDLE, resolveLayout_ = VK_NULL_HANDLE;
    VkPipeline points_ = VK_NULL_HANDLE, circles_ = VK_NULL_HANDLE, visibility_ = VK_NULL_HANDLE,
               accumulate_ = VK_NULL_HANDLE, resolve_ = VK_NULL_HANDLE;
    // Translucent frames: one sampled image (a depth or the composite) or three
    // (the layer's accumulation targets) per descriptor set.
    VkDescriptorSetLayout oneImageSetLayout_ = VK_NULL_HANDLE, threeImageSetLayout_ = VK_NULL_HANDLE;
    VkPipelineLayout oneImageLayout_ = VK_NULL_HANDLE, threeImageLayout_ = VK_NULL_HANDLE;
    VkDescriptorSet previousDepthSets_[2] = {}, layerSet_ = VK_NULL_HANDLE, compositeSet_ = VK_NULL_HANDLE;
    VkPipeline peel_ = VK_NULL_HANDLE, layer_ = VK_NULL_HANDLE, layerRest_ = VK_NULL_HANDLE,
               resolveLayer_ = VK_NULL_HANDLE, composite_ = VK_NULL_HANDLE;
    VkQueryPool queries_ = VK_NULL_HANDLE;
    gpu::Buffer surfels_, readback_;  // surfels_: the uploaded set's
    VkBuffer drawBuffer_ = VK_NULL_HANDLE;  // surfels_ or the caller's
    std::vector<DrawRange> ranges_;
    gpu::Image depth_, colorWeight_, normalWeight_, output_;
    gpu::Image depth2_, alphaWeight_, compositeImage_;  // translucent frames
    size_t splatCount_ = 0;
    double diagonal_ = 0;  // of the uploaded set, for the near plane
    bool ewaFrame_ = false;
};

}  // namespace surfcast
