// The client library's entry point for host applications: open a tile set by
// path or URL, update it with a camera every frame (level of detail, culling,
// streaming), and draw: record into the host's command buffer, or render to
// an offscreen image. surfcast-view's window and headless streaming use it;
// docs/CLIENT.md has a minimal example.
//
// A following client (ClientOptions::followSeconds) switches to a set's new
// versions as they are published: the new version streams beside the one
// drawn, adopting its unchanged nodes' kept blocks (only changed nodes are
// fetched), and replaces it in one frame once it has converged for the view
// (or after kMaxSwitchSeconds while the camera moves): no frame mixes two
// versions.
#pragma once

#include <chrono>
#include <memory>
#include <string>
#include <unordered_set>
#include <vector>

#include "splat_renderer.h"
#include "streamer.h"
#include "surfel_pool.h"
#include "version_watcher.h"

namespace surfcast {

struct ClientOptions {
    ClientOptions() { lod.splatBudget = 5'000'000; }
    LodParams lod;               // target projected spacing (px), culling, splats per frame
    int connections = 6;         // concurrent block requests
    HttpOptions http;            // URLs: headers, bearer token, CA file, timeout (tile_source.h)
    int decoders = 0;            // decode threads; 0: one per core
    size_t gpuBudget = 0;        // bytes of GPU memory for surfels; 0: 1 GiB or a quarter of the
                                 // device-local heap, whichever is smaller
    // Host memory for the compressed blocks kept so that setColoring()
    // fetches nothing (StreamOptions::keptBudget); 0: the stream's default.
    size_t blockCache = 0;
    RendererOptions renderer;
    // Colour by an attribute, hide classes: applied as blocks are decoded;
    // setColoring() changes it from the kept blocks (docs/CLIENT.md).
    Coloring coloring;
    // Follow the set: poll its tileset.json this often (seconds) and switch
    // to each new version (VersionWatcher); 0: show the version opened. A
    // follower splits gpuBudget in half: the version drawn, the one loading.
    double followSeconds = 0;
};

struct ClientFrame {
    size_t nodes = 0;            // drawn
    // CRC-32 of the drawn nodes' names ("L-X-Y-Z") in key order, joined by
    // commas: equal where the same nodes are drawn (the browser's nodesCrc).
    uint32_t nodesCrc = 0;
    size_t splats = 0;           // drawn
    size_t uploaded = 0, evicted = 0;  // nodes, this update
    bool converged = false;      // nothing the view needs is missing
    LodStats lod;
    StreamStats stream;          // of the version drawn
    // Following: the versions switched to since open(), and whether a newer
    // one is loading (its stream's stats in `next`).
    size_t version = 0;
    bool loadingVersion = false;
    StreamStats next;
    // The last poll's failure, else why the last new version was dropped
    // (its stream gave up); "" once a poll succeeds and a version is switched to.
    std::string followError;
};

class SurfcastClient {
public:
    // `ctx` must outlive the client: gpu::createContext, or gpu::wrapContext
    // around the host's own VkDevice.
    static Result<std::unique_ptr<SurfcastClient>> open(gpu::Context& ctx, const std::string& location,
                                                        const ClientOptions& options = {});

    const TilesetInfo& info() const { return stream_->info(); }
    // Kernel scale and shading the set was built for (the renderer's defaults),
    // for the current colouring: measured colours unlit, synthetic ones shaded.
    RenderSettings defaultSettings() const;

    // Colour by another attribute, or hide other classes: an error (nothing
    // changes) when the set lacks the attribute. The resident nodes are
    // decoded again from the blocks the stream kept (those beyond the block
    // cache fetched again); they
    // replace the old surfels over the next updates, which report converged
    // only once all have.
    Status setColoring(const Coloring& coloring);
    const Coloring& coloring() const { return options_.coloring; }

    // Chooses the nodes for this view, uploads what arrived and frees what
    // the stream evicted (GPU memory stays within gpuBudget). An error when
    // the set was rebuilt on the server since open() (open it again; a
    // follower switches to the new version instead) or the stream stopped
    // (StreamStats::gaveUp: a permanent failure, a node larger than
    // gpuBudget; a follower loading a newer version switches to it), each
    // time after this frame's uploads and evictions are applied.
    Result<ClientFrame> update(const Camera& camera, int width, int height);
    // Records the frame of the last update into `cmd`; output() is then in
    // TRANSFER_SRC_OPTIMAL for the host to blit or copy.
    void record(VkCommandBuffer cmd, const RenderSettings& settings);
    const gpu::Image& output() const { return renderer_->output(); }
    // Or: render the frame of the last update offscreen and read it back.
    Result<Image> renderImage(const RenderSettings& settings, GpuFrameStats* stats = nullptr);
    // GPU times of the last recorded frame, once it has completed.
    GpuFrameStats timings() const { return renderer_->timings(); }

    // A following client switches to a version loading after this long even
    // if it has not converged, where the version drawn has not converged
    // either (the camera keeps moving): the new version is drawn coarser
    // meanwhile, never mixed with the old. Under a still camera it waits for
    // the new version to converge, adopting the old one's blocks until then.
    static constexpr double kMaxSwitchSeconds = 5;

private:
    SurfcastClient() = default;
    // Applies a stream's evictions and arrivals to the pool, as slot `slot`'s
    // (a node arriving as the other slot's shares its pages).
    Status apply(int slot, StreamingSet& stream, StreamUpdate& u);
    void switchVersion();  // to next_, freeing the version drawn
    void dropNext(const std::string& why);  // the version loading failed: drawn as before
    std::unique_ptr<StreamingSet> stream_;  // the version drawn; destroyed after next_, which may adopt from it
    std::unique_ptr<VersionWatcher> watcher_;
    // Following: the newer version loading, its pool slot is 1 - slot_; when
    // it started loading (steady seconds).
    std::unique_ptr<StreamingSet> next_;
    std::chrono::steady_clock::time_point nextSince_;
    std::string nextError_;  // why the last version loading was dropped; "" since a switch
    int slot_ = 0;  // pool ids: a node's index times two, plus its version's slot
    std::unordered_set<uint32_t> inPool_[2];  // pool ids of each slot
    size_t versions_ = 0;
    std::unique_ptr<SurfelPool> pool_;
    std::unique_ptr<SplatRenderer> renderer_;
    ClientOptions options_;
    Vec3d origin_;
    double diagonal_ = 0;
    Camera camera_;
    int width_ = 0, height_ = 0;
};

}  // namespace surfcast
