// The client library's entry point for host applications: open a tile set by
// path or URL, update it with a camera every frame (level of detail, culling,
// streaming), and draw: record into the host's command buffer, or render to
// an offscreen image. surfcast-view's window and headless streaming use it;
// docs/CLIENT.md has a minimal example.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "splat_renderer.h"
#include "streamer.h"

namespace surfcast {

struct ClientOptions {
    LodParams lod;               // target projected spacing (px), culling
    int connections = 6;         // concurrent block requests
    RendererOptions renderer;
};

struct ClientFrame {
    size_t nodes = 0;            // drawn
    bool converged = false;      // nothing the view needs is missing
    LodStats lod;
    StreamStats stream;
};

class SurfcastClient {
public:
    // `ctx` must outlive the client.
    static Result<std::unique_ptr<SurfcastClient>> open(gpu::Context& ctx, const std::string& location,
                                                        const ClientOptions& options = {});

    const TilesetInfo& info() const { return stream_->info(); }
    // Kernel scale and shading the set was built for (the renderer's defaults).
    RenderSettings defaultSettings() const;

    // Chooses the nodes for this view and uploads them when they changed.
    Result<ClientFrame> update(const Camera& camera, int width, int height);
    // Records the frame of the last update into `cmd`; output() is then in
    // TRANSFER_SRC_OPTIMAL for the host to blit or copy.
    void record(VkCommandBuffer cmd, const RenderSettings& settings);
    const gpu::Image& output() const { return renderer_->output(); }
    // Or: render the frame of the last update offscreen and read it back.
    Result<Image> renderImage(const RenderSettings& settings, GpuFrameStats* stats = nullptr);
    // GPU times of the last recorded frame, once it has completed.
    GpuFrameStats timings() const { return renderer_->timings(); }

private:
    SurfcastClient() = default;
    std::unique_ptr<StreamingSet> stream_;
    std::unique_ptr<SplatRenderer> renderer_;
    ClientOptions options_;
    std::vector<uint32_t> drawn_;
    Vec3d origin_;
    Camera camera_;
    int width_ = 0, height_ = 0;
};

}  // namespace surfcast
