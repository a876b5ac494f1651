// A tile set streamed from a TileSource (local folder or HTTP): hierarchy
// pages and blocks on demand. Opening fetches tileset.json, hierarchy.bin's
// header and page table, and page 0 (docs/FORMAT.md); a further page is
// fetched when traversal reaches the node whose children it holds. Each
// update() traverses from the root (LodSelector), draws what is resident, and
// queues what the view still needs, pages first, then nodes coarsest gaps
// first, replacing the previous wants (requests that left the view are
// cancelled before they start).
//
//   update() ─wants─► fetch threads (bounded, keep-alive, batched) ─bytes─►
//   decode threads (CRC, Draco, pack, Morton) ─surfels─► next update():
//   `arrived` for the consumer to upload; `evicted` for it to free. A page
//   is checked by the fetch thread and joins the tree in the next update().
//
// Residency has a byte budget: beyond it, update() evicts the least recently
// used nodes that the view does not use (neither drawn nor refined through).
// Transient faults (server gone, timeouts, resets, short responses, HTTP 408,
// 429 and 5xx: Status::isTransient) are retried with exponential backoff,
// up to maxTries; permanent ones (other 4xx, a CRC or decoding failure of the
// set's fixed bytes, a page that fails its checks) stop fetching at once,
// naming the node or page. Neither stops drawing what is resident. After a
// fault, tileset.json is fetched again (at once after a permanent one, else
// at most every 2 s): if the set was rebuilt since it was opened, fetching
// stops and stats() says so, rather than failing on blocks that can never
// match the hierarchy.
//
// Resident nodes keep their compressed blocks (about a third of their 32-byte
// surfels) in host memory up to keptBudget, so setColoring() re-decodes what
// is resident without fetching: the recoloured nodes arrive again like
// fetched ones, replacing the old. Beyond the budget the least recently used
// resident nodes' blocks go, and a recolour fetches those again.
//
// A newer version of the set (a follower's: surfcast_client.h) streams as a
// set of its own that adopts the older one's kept blocks: a node with the
// same key, block CRC and size is decoded from them, not fetched; where
// decoding would give the very surfels the older one has resident (equal
// records and decodingKey), it arrives as that node's (ArrivedNode::sameAs),
// not decoded at all.
#pragma once

#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "lod_selection.h"
#include "surfel_set.h"
#include "tile_source.h"

namespace surfcast {

struct StreamOptions {
    int connections = 6;       // concurrent requests
    int decoders = 0;          // decode threads; 0: one per core
    // Bytes of resident surfels (32 B each, in granules). A node larger than
    // this could never be drawn: open() fails on one in page 0, and a later
    // page holding one stops the stream (StreamStats::gaveUp), naming it.
    size_t memoryBudget = size_t(1) << 30;
    size_t granule = 1;        // surfels: residency is counted in whole granules (the GPU pool's page)
    // Bytes of compressed blocks kept in host memory for recolouring (every
    // resident node's, for a full default budget: a set's blocks take about a
    // third of its surfels' 32 bytes each). Nodes that arrived since the last
    // update() keep theirs until it.
    size_t keptBudget = size_t(512) << 20;
    size_t batchBytes = 512 << 10;  // a batched request asks for up to this much (and 32 nodes)
    HttpOptions http;          // timeout (a stalled response fails and is retried), headers, token, CA
    // Tries of one node or page through transient faults before the stream
    // gives up (StreamStats::gaveUp). With the backoff (0.1 s doubling to
    // 5 s), 8 tries span about 11 s: past a server restart, short of a user's
    // patience. A permanent failure is not retried.
    int maxTries = 8;
    Coloring coloring;  // what decoded surfels are coloured by, and which classes are dropped (setColoring)
};

struct StreamStats {
    uint64_t bytesDownloaded = 0;  // blocks
    uint64_t hierarchyBytes = 0;   // of hierarchy.bin: header, page table and the pages fetched
    size_t pages = 0;              // hierarchy pages fetched, page 0 included
    size_t requests = 0, requestsInFlight = 0, nodesFetched = 0, inFlight = 0, queued = 0, resident = 0, failures = 0, evictions = 0;
    size_t residentBytes = 0;  // inFlight: nodes being fetched or decoded
    size_t keptBytes = 0;      // compressed blocks kept for recolouring (at most keptBudget after an update)
    size_t refetched = 0;      // blocks fetched again to recolour nodes whose kept blocks had gone
    size_t adopted = 0;        // nodes an older version had (adopt()), not fetched: decoded from its kept block, or
    size_t shared = 0;         // drawn as it draws them (ArrivedNode::sameAs), not decoded
    size_t recoloring = 0;     // resident nodes still to be re-decoded for the latest setColoring
    double fetchMs = 0, decodeMs = 0;  // of the last request and the last block
    std::string lastError;
    // The set's tileset.json differs from the one opened (rebuilt on the
    // server): nothing more is fetched; open it again.
    bool setChanged = false;
    // A node or page failed permanently (refused, not found, a block that
    // fails its CRC or does not decode), or through StreamOptions::maxTries
    // transient faults in a row (a server gone for good), or two nodes claim
    // one page, or a page holds a node larger than memoryBudget: nothing
    // more is fetched, and lastError says which node and why.
    bool gaveUp = false;
};

// One node's surfels, packed for the GPU and Morton-ordered within the node,
// positions relative to the set's render origin (emptySurfelSet(info).origin).
struct ArrivedNode {
    uint32_t index;
    std::shared_ptr<const SurfelSet> surfels;
    // Null surfels: the donor's node of this index (adopt()) as it has them
    // resident, which the consumer draws for this one too; or, where it has
    // let that go since, hands back with forget().
    std::optional<uint32_t> sameAs = std::nullopt;
};

struct StreamUpdate {
    std::vector<SelectedNode> draw;      // resident nodes to draw now
    std::vector<ArrivedNode> arrived;    // resident since the last update, or recoloured: upload these
                                         // (a recoloured node replaces the surfels it had)
    std::vector<uint32_t> evicted;       // no longer resident: free these
    LodStats lod;
    bool converged = false;              // nothing the view needs is missing or still to be recoloured
};

class StreamingSet {
public:
    static Result<std::unique_ptr<StreamingSet>> open(const std::string& location, const StreamOptions& options = {});
    // The same through `source` (openTileSource(location)), which the caller
    // may cancel() from another thread to end the opening at once.
    static Result<std::unique_ptr<StreamingSet>> open(std::shared_ptr<TileSource> source, const std::string& location,
                                                      const StreamOptions& options = {});
    ~StreamingSet();

    const TilesetInfo& info() const { return info_; }
    // The nodes known so far (pages fetched); update() appends, keeping indices.
    const std::vector<NodeRecord>& nodes() const { return selector_->nodes(); }
    const LodSelector& selector() const { return *selector_; }
    const StreamOptions& options() const { return options_; }

    // The nodes to draw for this view; the consumer takes ownership of the
    // surfels that arrived and must drop the evicted ones.
    StreamUpdate update(const Camera& camera, int width, int height, const LodParams& params);
    StreamStats stats() const;
    // Colour and filter by `coloring` from now on: nodes decoded later use
    // it, and every resident node is re-decoded from its kept block (those
    // beyond keptBudget fetched again) and arrives again in a later update.
    // Until then the old surfels are drawn, and update() reports converged =
    // false.
    void setColoring(const Coloring& coloring);
    // Bytes a node occupies when resident (whole granules of 32-byte surfels).
    size_t residentCost(uint32_t index) const;
    // tileset.json as opened: the version this stream shows.
    const std::vector<uint8_t>& tilesetJson() const { return tilesetJson_; }

    using Block = std::shared_ptr<const std::vector<uint8_t>>;
    // Take the nodes `donor` (another version of this set) holds unchanged
    // from it rather than fetch them; nullptr: no longer. The donor must
    // outlive this call's effect: call adopt(nullptr) before destroying it.
    void adopt(const StreamingSet* donor);
    // This set's node with the record's key, where its block has the
    // record's CRC and size and is kept: its index, the block, and whether
    // it is resident with the very surfels a set of decoding key `key`
    // would decode for the record (sameDecoding). Thread-safe.
    struct Kept {
        uint32_t index;
        Block block;
        bool sameSurfels;
    };
    std::optional<Kept> kept(const NodeRecord& record, const std::string& key) const;
    // A node handed over as sameAs whose donor copy the consumer no longer
    // has: no longer resident, so that a later update() asks for it again.
    void forget(uint32_t index);

private:
    StreamingSet() = default;
    void fetchLoop();
    void decodeLoop();
    void fail(uint32_t node, const Status& status);        // with mutex_ held
    // A node's or page's failed attempt: retried after a backoff while
    // transient and under maxTries, else the stream stops (a permanent one
    // after a check for a rebuilt set). With mutex_ held.
    void failed(std::pair<int, double>* attempts, const std::string& what, const Status& status);
    bool fetchPage(std::unique_lock<std::mutex>& lock);    // one wanted page, if any is due
    // Page `page`, whose first record is `root`'s, fetched and checked
    // (readHierarchyPage), without mutex_.
    Result<std::vector<NodeRecord>> fetchPageRecords(uint32_t page, const NodeKey& root) const;
    void stop(const std::string& message);                 // gave up, with mutex_ held
    void noteFailure(const std::string& message);          // counted and kept for stats(), with mutex_ held
    void addPages();                                        // those fetched, to the tree, with mutex_ held
    // An error naming the first of `records` that could never be resident
    // (larger than memoryBudget).
    Status checkFitsBudget(const std::vector<NodeRecord>& records) const;
    void checkForRebuild(std::unique_lock<std::mutex>& lock);
    void keep(uint32_t node, Block bytes);  // with mutex_ held
    void unkeep(uint32_t node);             // with mutex_ held
    // Fetches blocks of resident nodes a recolour needs again, if any are
    // due; with mutex_ held (released while fetching).
    bool refetchForRecolor(std::unique_lock<std::mutex>& lock);

    std::shared_ptr<TileSource> source_;
    std::vector<uint8_t> tilesetJson_;  // as opened
    TilesetInfo info_;
    StreamOptions options_;
    std::unique_ptr<LodSelector> selector_;
    HierarchyIndex hierarchy_;

    struct Resident {
        uint64_t lastUsed = 0;  // frame number
        size_t bytes = 0;
    };
    struct Fetched {
        uint32_t node;
        Block bytes;
        bool recolor = false;    // a resident node's block, to decode with the new coloring
        bool refetched = false;  // fetched again for that (its kept copy had gone)
        bool adopted = false;    // the donor's kept block, not fetched
    };

    mutable std::mutex mutex_;
    std::condition_variable wakeFetch_, wakeDecode_;
    uint64_t frame_ = 0;
    std::unordered_map<uint32_t, Resident> resident_;
    size_t residentBytes_ = 0, pendingBytes_ = 0;  // pending: in flight, decoding or arrived
    std::vector<std::pair<uint32_t, double>> wanted_;  // by priority, highest last
    std::unordered_map<uint32_t, int> pending_;        // node -> 1 while fetched or decoded
    std::deque<Fetched> fetched_;                       // waiting for a decoder
    std::vector<ArrivedNode> arrived_;                  // decoded, not yet handed over
    std::unordered_map<uint32_t, Block> kept_;          // blocks of resident and arrived nodes, within keptBudget
    size_t keptBytes_ = 0;
    std::vector<uint32_t> refetch_;                     // resident nodes to recolour whose blocks went
    std::pair<int, double> refetchFailed_{0, 0};        // attempts, retry time (s) of the last failed refetch
    uint64_t coloringVersion_ = 0;                      // setColoring calls so far
    size_t recolors_ = 0;                               // recolour jobs not yet handed over or dropped
    std::unordered_map<uint32_t, std::pair<int, double>> failed_;  // node -> attempts, retry time (s)
    // Pages: wanted as (the node whose children they hold, priority), highest
    // last; requested by page index (false while fetching or waiting for
    // update(), true once in the tree); fetched, waiting for update(); failed
    // by page index: attempts, retry time (s).
    std::vector<std::pair<uint32_t, double>> wantedPages_;
    std::unordered_map<uint32_t, bool> pages_;
    std::vector<std::pair<uint32_t, std::vector<NodeRecord>>> pagesFetched_;
    std::unordered_map<uint32_t, std::pair<int, double>> failedPages_;
    StreamStats stats_;
    bool checkDue_ = false;  // a fault happened: has the set changed?
    bool checking_ = false;  // a check is in flight
    double lastCheck_ = 0;   // when the last check began
    // The first permanent failure and when: the stream stops with it unless
    // the set changed.
    std::string permanent_;
    double permanentAt_ = 0;
    bool stopping_ = false;
    const StreamingSet* donor_ = nullptr;  // adopt()
    std::string decodingKey_;              // of info_ and the colouring (surfel_set.h)
    std::vector<std::thread> fetchers_, decoders_;
};

}  // namespace surfcast
