#include "surfcast_client.h"

#include <algorithm>
#include <chrono>

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
uint32_t poolId(int slot, uint32_t index) { return index * 2 + uint32_t(slot); }
}  // namespace

Result<std::unique_ptr<SurfcastClient>> SurfcastClient::open(gpu::Context& ctx, const std::string& location,
                                                             const ClientOptions& options) {
    std::unique_ptr<SurfcastClient> c(new SurfcastClient);
    c->options_ = options;
    StreamOptions stream;
    stream.connections = options.connections;
    stream.http = options.http;
    stream.decoders = options.decoders;
    const size_t gpuBudget = options.gpuBudget ? options.gpuBudget : defaultGpuBudget(ctx);
    stream.memoryBudget = options.followSeconds > 0 ? gpuBudget / 2 : gpuBudget;
    stream.granule = SurfelPool::kPageSurfels;
    if (options.blockCache) stream.keptBudget = options.blockCache;
    stream.coloring = options.coloring;
    auto opened = StreamingSet::open(location, stream);
    if (!opened) return opened.status();
    c->stream_ = std::move(*opened);
    if (auto by = resolveColorBy(options.coloring.by, c->stream_->info()); !by)
        return Status::error(location + ": " + by.status().message());
    if (options.followSeconds > 0)
        c->watcher_ = std::make_unique<VersionWatcher>(location, stream, c->stream_->tilesetJson(), options.followSeconds);
    auto pool = SurfelPool::create(ctx, gpuBudget);
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
    if (next_) next_->setColoring(coloring);
    return {};
}

Status SurfcastClient::apply(int slot, StreamingSet& stream, StreamUpdate& u) {
    for (uint32_t i : u.evicted) {
        pool_->release(poolId(slot, i));
        inPool_[slot].erase(poolId(slot, i));
    }
    std::vector<std::pair<uint32_t, const SurfelSet*>> uploads;
    std::vector<uint32_t> forgotten;
    for (const ArrivedNode& a : u.arrived) {
        pool_->release(poolId(slot, a.index));  // a recoloured node replaces its old surfels
        if (!a.surfels) {  // the other version's copy, unless it went since (asked for again)
            if (a.sameAs && pool_->share(poolId(slot, a.index), poolId(1 - slot, *a.sameAs))) inPool_[slot].insert(poolId(slot, a.index));
            else forgotten.push_back(a.index);
            continue;
        }
        uploads.push_back({poolId(slot, a.index), a.surfels.get()});
        inPool_[slot].insert(poolId(slot, a.index));
    }
    for (uint32_t i : forgotten) stream.forget(i);
    // Not drawn this frame (it is not resident any more), and wanted again.
    std::erase_if(u.draw, [&](const SelectedNode& s) { return std::find(forgotten.begin(), forgotten.end(), s.index) != forgotten.end(); });
    if (!forgotten.empty()) u.converged = false;
    return pool_->upload(uploads);
}

void SurfcastClient::dropNext(const std::string& why) {
    for (uint32_t id : inPool_[1 - slot_]) pool_->release(id);
    inPool_[1 - slot_].clear();
    next_.reset();
    watcher_->showing(stream_->tilesetJson());
    nextError_ = why;
}

void SurfcastClient::switchVersion() {
    for (uint32_t id : inPool_[slot_]) pool_->release(id);
    inPool_[slot_].clear();
    next_->adopt(nullptr);  // before the donor goes
    stream_ = std::move(next_);
    slot_ = 1 - slot_;
    ++versions_;
    nextError_.clear();
    origin_ = emptySurfelSet(stream_->info()).origin;
    const Box3d& b = stream_->info().bounds;
    diagonal_ = b.empty() ? 0 : length(b.max - b.min);
}

Result<ClientFrame> SurfcastClient::update(const Camera& camera, int width, int height) {
    ClientFrame frame;
    if (watcher_ && !next_) {
        next_ = watcher_->take();
        if (next_) {
            next_->setColoring(options_.coloring);  // as changed since the watcher opened it
            next_->adopt(stream_.get());
            nextSince_ = std::chrono::steady_clock::now();
        }
    }
    StreamUpdate u = stream_->update(camera, width, height, options_.lod);
    SC_TRY(apply(slot_, *stream_, u));
    size_t uploaded = u.arrived.size(), evicted = u.evicted.size();
    if (next_) {
        StreamUpdate n = next_->update(camera, width, height, options_.lod);
        const Status applied = apply(1 - slot_, *next_, n);
        uploaded += n.arrived.size();
        evicted += n.evicted.size();
        const StreamStats loading = next_->stats();
        if (!applied.ok() || loading.gaveUp || loading.setChanged) {
            // Drawn as before; the watcher opens the newest version again.
            dropNext(applied.ok() ? loading.lastError : applied.message());
        } else if (n.converged || (!u.converged && std::chrono::steady_clock::now() - nextSince_ > std::chrono::duration<double>(kMaxSwitchSeconds))) {
            // (A drawn version that stopped, a rebuild found after a fault,
            // keeps its resident nodes until then.)
            switchVersion();
            u = std::move(n);
        }
    }
    // Drawn in key order: the image depends neither on the order nodes
    // arrived in nor on the indices pages got (their arrival order, and the
    // set's page depth).
    std::vector<uint32_t> drawn;
    for (const SelectedNode& s : u.draw) drawn.push_back(s.index);
    const std::vector<NodeRecord>& nodes = stream_->nodes();
    std::sort(drawn.begin(), drawn.end(), [&](uint32_t a, uint32_t b) { return nodes[a].key < nodes[b].key; });
    std::vector<uint32_t> ids;
    for (uint32_t i : drawn) ids.push_back(poolId(slot_, i));
    renderer_->setDraws(pool_->buffer(), pool_->ranges(ids), diagonal_);
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
    frame.uploaded = uploaded;
    frame.evicted = evicted;
    frame.converged = u.converged && !next_;  // a version loading is wanted too
    frame.lod = std::move(u.lod);
    frame.stream = stream_->stats();
    frame.version = versions_;
    frame.loadingVersion = next_ != nullptr;
    if (next_) frame.next = next_->stats();
    if (watcher_) frame.followError = watcher_->lastError();
    if (frame.followError.empty()) frame.followError = nextError_;
    // A follower shows the version it has until the watcher finds the new one.
    if ((frame.stream.setChanged && !watcher_) || (frame.stream.gaveUp && !next_)) return Status::error(frame.stream.lastError);
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
