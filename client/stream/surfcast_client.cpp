#include "surfcast_client.h"

#include <algorithm>

#include "crc32.h"

namespace surfcast {

namespace {
// 1 GiB, or a quarter of the largest device-local heap if that is smaller.
size_t defaultGpuBudget(gpu::Context& ctx) {
    VkPhysicalDeviceMemoryProperties memory;
    vkGetPhysicalDeviceMemoryProperties(ctx.physicalDevice, &memory);
    VkDeviceSize heap = 0;
    for (uint32_t i = 0; i < memory.memoryHeapCount; ++i)
        if (memory.memoryHeaps[i].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) heap = std::max(heap, memory.memoryHeaps[i].size);
    return std::min<size_t>(size_t(1) << 30, heap ? heap / 4 : size_t(1) << 30);
}
}  // namespace

Result<std::unique_ptr<SurfcastClient>> SurfcastClient::open(gpu::Context& ctx, const std::string& location,
                                                             const ClientOptions& options) {
    std::unique_ptr<SurfcastClient> c(new SurfcastClient);
    c->options_ = options;
    StreamOptions stream;
    stream.connections = options.connections;
    stream.http = options.http;
    stream.decoders = options.decoders;
    stream.memoryBudget = options.gpuBudget ? options.gpuBudget : defaultGpuBudget(ctx);
    stream.granule = SurfelPool::kPageSurfels;
    if (options.blockCache) stream.keptBudget = options.blockCache;
    stream.coloring = options.coloring;
    auto opened = StreamingSet::open(location, stream);
    if (!opened) return opened.status();
    c->stream_ = std::move(*opened);
    if (auto by = resolveColorBy(options.coloring.by, c->stream_->info()); !by)
        return Status::error(location + ": " + by.status().message());
    auto pool = SurfelPool::create(ctx, stream.memoryBudget);
    if (!pool) return pool.status();
    c->pool_ = std::move(*pool);
    auto renderer = SplatRenderer::create(ctx, options.renderer);
    if (!renderer) return renderer.status();
    c->renderer_ = std::move(*renderer);
    c->origin_ = emptySurfelSet(c->stream_->info()).origin;
    const Box3d& b = c->stream_->info().bounds;
    c->diagonal_ = b.empty() ? 0 : length(b.max - b.min);
    return c;
}

RenderSettings SurfcastClient::defaultSettings() const {
    const SurfelSet empty = emptySurfelSet(info(), options_.coloring);
    return settingsForSet(info().kernelScale, empty.hasColor, empty.normalsOriented, empty.translucent);
}

Status SurfcastClient::setColoring(const Coloring& coloring) {
    if (auto by = resolveColorBy(coloring.by, info()); !by) return by.status();
    options_.coloring = coloring;
    stream_->setColoring(coloring);
    return {};
}

Result<ClientFrame> SurfcastClient::update(const Camera& camera, int width, int height) {
    ClientFrame frame;
    StreamUpdate u = stream_->update(camera, width, height, options_.lod);
    for (uint32_t i : u.evicted) pool_->release(i);
    std::vector<std::pair<uint32_t, const SurfelSet*>> uploads;
    for (const ArrivedNode& a : u.arrived) {
        pool_->release(a.index);  // a recoloured node replaces its old surfels
        uploads.push_back({a.index, a.surfels.get()});
    }
    SC_TRY(pool_->upload(uploads));
    // Drawn in key order: the image depends neither on the order nodes
    // arrived in nor on the indices pages got (their arrival order, and the
    // set's page depth).
    std::vector<uint32_t> drawn;
    for (const SelectedNode& s : u.draw) drawn.push_back(s.index);
    const std::vector<NodeRecord>& nodes = stream_->nodes();
    std::sort(drawn.begin(), drawn.end(), [&](uint32_t a, uint32_t b) { return nodes[a].key < nodes[b].key; });
    renderer_->setDraws(pool_->buffer(), pool_->ranges(drawn), diagonal_);
    SC_TRY(renderer_->resize(uint32_t(width), uint32_t(height)));
    camera_ = camera;
    width_ = width;
    height_ = height;
    frame.nodes = drawn.size();
    std::string names;
    for (uint32_t i : drawn) {
        if (!names.empty()) names += ',';
        names += nodes[i].key.name();
    }
    frame.nodesCrc = crc32(names.data(), names.size());
    frame.splats = renderer_->splatCount();
    frame.uploaded = u.arrived.size();
    frame.evicted = u.evicted.size();
    frame.converged = u.converged;
    frame.lod = std::move(u.lod);
    frame.stream = stream_->stats();
    if (frame.stream.setChanged || frame.stream.gaveUp) return Status::error(frame.stream.lastError);
    return frame;
}

void SurfcastClient::record(VkCommandBuffer cmd, const RenderSettings& settings) {
    auto view = makeViewTransform(camera_, origin_, width_, height_);
    if (!view) return;  // update() was not called, or the camera is degenerate
    renderer_->record(cmd, *view, settings);
}

Result<Image> SurfcastClient::renderImage(const RenderSettings& settings, GpuFrameStats* stats) {
    auto view = makeViewTransform(camera_, origin_, width_, height_);
    if (!view) return view.status();
    return renderer_->render(*view, settings, stats);
}

}  // namespace surfcast
