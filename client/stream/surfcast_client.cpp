#include "surfcast_client.h"

#include "surfel_set.h"

namespace surfcast {

Result<std::unique_ptr<SurfcastClient>> SurfcastClient::open(gpu::Context& ctx, const std::string& location,
                                                             const ClientOptions& options) {
    std::unique_ptr<SurfcastClient> c(new SurfcastClient);
    c->options_ = options;
    auto stream = StreamingSet::open(location, options.connections);
    if (!stream) return stream.status();
    c->stream_ = std::move(*stream);
    auto renderer = SplatRenderer::create(ctx, options.renderer);
    if (!renderer) return renderer.status();
    c->renderer_ = std::move(*renderer);
    c->origin_ = emptySurfelSet(c->stream_->info()).origin;
    return c;
}

RenderSettings SurfcastClient::defaultSettings() const {
    RenderSettings s;
    s.kernelScale = float(info().kernelScale);
    s.shading = info().colorBits ? Shading::Unlit : Shading::Lambert;
    return s;
}

Result<ClientFrame> SurfcastClient::update(const Camera& camera, int width, int height) {
    ClientFrame frame;
    auto selected = stream_->update(camera, width, height, options_.lod, &frame.lod, &frame.converged);
    std::vector<uint32_t> now;
    for (const auto& s : selected) now.push_back(s.index);
    if (now != drawn_) {  // rebuild and upload only when the drawn nodes change
        SurfelSet set = emptySurfelSet(info());
        for (uint32_t i : now)
            if (auto block = stream_->block(i)) appendNode(set, info(), stream_->nodes()[i], *block);
        sortMorton(set);
        SC_TRY(renderer_->upload(set));
        drawn_ = std::move(now);
    }
    SC_TRY(renderer_->resize(uint32_t(width), uint32_t(height)));
    camera_ = camera;
    width_ = width;
    height_ = height;
    frame.nodes = drawn_.size();
    frame.stream = stream_->stats();
    return frame;
}

void SurfcastClient::record(VkCommandBuffer cmd, const RenderSettings& settings) {
    auto view = makeViewTransform(camera_, origin_, width_, height_);
    if (!view) return;  // update() was not called, or the camera is degenerate
    renderer_->record(cmd, makeFrameParams(*view, settings, renderer_->nearPlane(*view)));
}

Result<Image> SurfcastClient::renderImage(const RenderSettings& settings, GpuFrameStats* stats) {
    auto view = makeViewTransform(camera_, origin_, width_, height_);
    if (!view) return view.status();
    return renderer_->render(*view, settings, stats);
}

}  // namespace surfcast
