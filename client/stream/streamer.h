// A tile set streamed from a TileSource (local folder or HTTP): the hierarchy
// up front, blocks on demand. Each update() traverses from the root
// (LodSelector), draws what is resident, and queues what the view still needs,
// coarsest gaps first. Worker threads fetch (bounded concurrency, keep-alive),
// check the CRC, decode, and retry failures with exponential backoff; a fault
// never stops drawing what is resident.
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "block_codec.h"
#include "lod_selection.h"
#include "tile_source.h"

namespace surfcast {

struct StreamStats {
    uint64_t bytesDownloaded = 0;
    size_t requests = 0, inFlight = 0, queued = 0, resident = 0, failures = 0;
    double fetchMs = 0, decodeMs = 0;  // of the last block
    std::string lastError;
};

class StreamingSet {
public:
    static Result<std::unique_ptr<StreamingSet>> open(const std::string& location, int connections = 6);
    ~StreamingSet();

    const TilesetInfo& info() const { return info_; }
    const std::vector<NodeRecord>& nodes() const { return selector_->nodes(); }

    // The nodes to draw now (all resident); queues the missing ones the view
    // needs, replacing the previous wants. `converged` is set when nothing the
    // view needs is missing.
    std::vector<SelectedNode> update(const Camera& camera, int width, int height, const LodParams& params,
                                     LodStats* lod, bool* converged);
    // The decoded block of a resident node (nullptr if not resident).
    std::shared_ptr<const BlockData> block(uint32_t index) const;
    StreamStats stats() const;

private:
    StreamingSet() = default;
    void work();

    std::unique_ptr<TileSource> source_;
    TilesetInfo info_;
    std::unique_ptr<LodSelector> selector_;

    mutable std::mutex mutex_;
    std::condition_variable wake_;
    std::unordered_map<uint32_t, std::shared_ptr<const BlockData>> resident_;
    std::vector<std::pair<uint32_t, double>> wanted_;  // by priority, highest last
    std::unordered_map<uint32_t, int> inFlight_;        // node -> 1
    std::unordered_map<uint32_t, std::pair<int, double>> failed_;  // node -> attempts, retry time (s)
    StreamStats stats_;
    bool stopping_ = false;
    std::vector<std::thread> workers_;
};

}  // namespace surfcast
