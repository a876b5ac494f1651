#include "streamer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <unordered_set>

#include "block_codec.h"
#include "crc32.h"
#include "http_tile_source.h"
#include "tileset_reader.h"

namespace surfcast {

namespace {
double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
// Retry after 0.1 s, doubling per failure up to 5 s: a restarting server
// comes back without the client hammering it.
double backoffSeconds(int attempts) { return std::min(5.0, 0.1 * std::pow(2.0, attempts - 1)); }
constexpr size_t kMaxBatchNodes = 32;
}  // namespace

Result<std::unique_ptr<StreamingSet>> StreamingSet::open(const std::string& location, const StreamOptions& options) {
    auto source = openTileSource(location, options.http);
    if (!source) return source.status();
    return open(std::shared_ptr<TileSource>(std::move(*source)), location, options);
}

Result<std::unique_ptr<StreamingSet>> StreamingSet::open(std::shared_ptr<TileSource> source, const std::string& location,
                                                         const StreamOptions& options) {
    std::unique_ptr<StreamingSet> s(new StreamingSet);
    s->options_ = options;
    s->options_.granule = std::max<size_t>(1, options.granule);
    s->source_ = std::move(source);
    auto json = s->source_->file("tileset.json", kMaxTilesetJsonBytes);
    if (!json) return json.status();
    auto info = readTilesetJson(std::string(json->begin(), json->end()), location + "/tileset.json");
    if (!info) return info.status();
    s->tilesetJson_ = std::move(*json);
    s->info_ = *info;
    s->decodingKey_ = decodingKey(s->info_, s->options_.coloring);
    s->source_->setBlocksLayout(BlocksLayout(blocksPartsOf(s->info_)));
    // hierarchy.bin's header and page table, then page 0.
    const std::string what = location + "/" + s->info_.hierarchyFile;
    const uint64_t indexBytes = kHierarchyHeaderSize + uint64_t(kPageEntrySize) * s->info_.hierarchyPages;
    if (s->info_.hierarchyPages == 0 || indexBytes > s->info_.hierarchyBytes)
        return Status::error(location + "/tileset.json: " + std::to_string(s->info_.hierarchyPages) +
                             " hierarchy pages do not fit hierarchy.bin's " + std::to_string(s->info_.hierarchyBytes) + " bytes");
    auto head = s->source_->range(s->info_.hierarchyFile, 0, indexBytes);
    if (!head) return head.status();
    auto index = readHierarchyIndex(*head, s->info_.hierarchyBytes, what);
    if (!index) return index.status();
    s->hierarchy_ = std::move(*index);
    auto page = s->fetchPageRecords(0, NodeKey{});
    if (!page) return page.status();
    SC_TRY(s->checkFitsBudget(*page));
    s->selector_ = std::make_unique<LodSelector>(s->info_, std::move(*page));
    s->pages_[0] = true;
    s->stats_.pages = 1;
    s->stats_.hierarchyBytes = indexBytes + uint64_t(s->hierarchy_.pages[0].records) * kRecordSize;
    int decoders = options.decoders > 0 ? options.decoders : int(std::max(1u, std::thread::hardware_concurrency()));
    for (int i = 0; i < std::max(1, options.connections); ++i) s->fetchers_.emplace_back([p = s.get()] { p->fetchLoop(); });
    for (int i = 0; i < decoders; ++i) s->decoders_.emplace_back([p = s.get()] { p->decodeLoop(); });
    return s;
}

Result<std::vector<NodeRecord>> StreamingSet::fetchPageRecords(uint32_t page, const NodeKey& root) const {
    if (page >= hierarchy_.pages.size())
        return Status::error(source_->describe() + "/hierarchy.bin: node " + root.name() + " points to page " +
                             std::to_string(page) + " of " + std::to_string(hierarchy_.pages.size()));
    const HierarchyPageEntry& entry = hierarchy_.pages[page];
    auto bytes = source_->range(info_.hierarchyFile, entry.offset, uint64_t(entry.records) * kRecordSize);
    if (!bytes) return bytes.status();
    return readHierarchyPage(hierarchy_, page, *bytes, root, info_.blocksBytes, source_->describe() + "/" + info_.hierarchyFile);
}

StreamingSet::~StreamingSet() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    if (source_) source_->cancel();  // fetch threads waiting on a stalled host return now
    wakeFetch_.notify_all();
    wakeDecode_.notify_all();
    for (auto& t : fetchers_) t.join();
    for (auto& t : decoders_) t.join();
}

static_assert(sizeof(gpu_types::GpuSurfel) == 32, "residentBytes() counts 32 bytes per surfel");
size_t StreamingSet::residentCost(uint32_t index) const {
    return residentBytes(nodes()[index].surfelCount, options_.granule);
}

Status StreamingSet::checkFitsBudget(const std::vector<NodeRecord>& records) const {
    for (const NodeRecord& r : records) {
        const size_t cost = residentBytes(r.surfelCount, options_.granule);
        if (cost > options_.memoryBudget)
            return Status::error(source_->describe() + ": node " + r.key.name() + " needs " + std::to_string(cost >> 10) +
                                 " KiB resident, more than the memory budget of " +
                                 std::to_string(options_.memoryBudget >> 10) + " KiB (--gpu-budget)");
    }
    return {};
}

StreamUpdate StreamingSet::update(const Camera& camera, int width, int height, const LodParams& params) {
    StreamUpdate u;
    {
        std::lock_guard lock(mutex_);
        ++frame_;
        addPages();
        // What decoded since the last update is resident from now on.
        u.arrived.swap(arrived_);
        for (const ArrivedNode& a : u.arrived) {
            if (resident_.count(a.index)) {  // recoloured: resident already
                --recolors_;
                continue;
            }
            size_t bytes = residentCost(a.index);
            resident_[a.index] = {0, bytes};  // used from the selection on
            residentBytes_ += bytes;
            pendingBytes_ -= bytes;
        }
        LodParams bounded = params;  // what the view uses must fit the cache
        bounded.memoryBudget = std::min(params.memoryBudget, options_.memoryBudget);
        bounded.granule = options_.granule;
        u.draw = selector_->select(camera, width, height, bounded,
                                   [&](uint32_t i) { return resident_.count(i) != 0; }, &u.lod);
        for (uint32_t i : u.lod.used) resident_[i].lastUsed = frame_;

        wanted_.clear();
        size_t wantedBytes = 0;
        for (const auto& [node, priority] : u.lod.missing)
            if (!pending_.count(node) && !stats_.setChanged && !stats_.gaveUp) {
                wanted_.push_back({node, priority});
                wantedBytes += residentCost(node);
            }
        std::stable_sort(wanted_.begin(), wanted_.end(), [](auto& a, auto& b) { return a.second < b.second; });
        // Make room for what the view wants: least recently used first, never
        // a node this frame uses.
        if (residentBytes_ + pendingBytes_ + wantedBytes > options_.memoryBudget) {
            std::vector<std::pair<uint64_t, uint32_t>> lru;
            for (const auto& [node, r] : resident_)
                if (r.lastUsed != frame_) lru.push_back({r.lastUsed, node});
            std::sort(lru.begin(), lru.end());
            for (const auto& [used, node] : lru) {
                if (residentBytes_ + pendingBytes_ + wantedBytes <= options_.memoryBudget) break;
                residentBytes_ -= resident_[node].bytes;
                resident_.erase(node);
                unkeep(node);
                u.evicted.push_back(node);
                ++stats_.evictions;
            }
            // A node that arrived for an earlier view and is evicted at once
            // never reaches the consumer.
            std::unordered_set<uint32_t> gone(u.evicted.begin(), u.evicted.end());
            std::erase_if(u.arrived, [&](const ArrivedNode& a) { return gone.count(a.index) != 0; });
        }
        // Kept blocks beyond their budget: the least recently used resident
        // nodes' go first (a recolour fetches them again).
        if (keptBytes_ > options_.keptBudget) {
            std::vector<std::pair<uint64_t, uint32_t>> lru;
            for (const auto& [node, r] : resident_)
                if (kept_.count(node)) lru.push_back({r.lastUsed, node});
            std::sort(lru.begin(), lru.end());
            for (const auto& [used, node] : lru) {
                if (keptBytes_ <= options_.keptBudget) break;
                unkeep(node);
            }
        }
        wantedPages_.clear();
        for (const auto& [node, priority] : u.lod.missingPages) {
            auto requested = pages_.find(nodes()[node].childPage);
            if (requested == pages_.end()) wantedPages_.push_back({node, priority});
            else if (requested->second)  // in the tree, yet not this node's children
                stop(source_->describe() + "/hierarchy.bin: node " + nodes()[node].key.name() + " points to page " +
                     std::to_string(requested->first) + ", which holds another node's children");
        }
        if (stats_.setChanged || stats_.gaveUp) wantedPages_.clear();
        std::stable_sort(wantedPages_.begin(), wantedPages_.end(), [](auto& a, auto& b) { return a.second < b.second; });
        stats_.queued = wanted_.size() + wantedPages_.size();
        u.converged = u.lod.missing.empty() && u.lod.missingPages.empty() && recolors_ == 0;
    }
    wakeFetch_.notify_all();
    return u;
}

StreamStats StreamingSet::stats() const {
    std::lock_guard lock(mutex_);
    StreamStats s = stats_;
    s.inFlight = pending_.size();
    s.resident = resident_.size();
    s.residentBytes = residentBytes_;
    s.keptBytes = keptBytes_;
    s.recoloring = recolors_;
    return s;
}

void StreamingSet::setColoring(const Coloring& coloring) {
    {
        std::lock_guard lock(mutex_);
        options_.coloring = coloring;
        decodingKey_ = decodingKey(info_, coloring);
        ++coloringVersion_;
        // Recolour jobs still queued are superseded by the ones queued here;
        // those being fetched or decoded are dropped when they finish.
        recolors_ -= size_t(std::erase_if(fetched_, [](const Fetched& f) { return f.recolor; }));
        recolors_ -= refetch_.size();
        refetch_.clear();
        // Decoded but not yet handed over: a recolour is queued again below;
        // a fetched node is decoded again, as if just fetched.
        for (const ArrivedNode& a : arrived_) {
            if (resident_.count(a.index)) {
                --recolors_;
                continue;
            }
            pending_[a.index] = 1;
            fetched_.push_back({a.index, kept_.at(a.index), false, false, a.sameAs.has_value()});
        }
        arrived_.clear();
        // Blocks that went are fetched again, most recently used last (the
        // fetch loop takes from the back), unless the stream has stopped:
        // then those nodes keep their colours.
        const bool stopped = stats_.gaveUp || stats_.setChanged;
        std::vector<std::pair<uint64_t, uint32_t>> missing;
        for (const auto& [node, r] : resident_) {
            auto kept = kept_.find(node);
            if (kept != kept_.end()) {
                fetched_.push_back({node, kept->second, true});
                ++recolors_;
            } else if (!stopped) {
                missing.push_back({r.lastUsed, node});
            }
        }
        std::sort(missing.begin(), missing.end());
        for (const auto& [used, node] : missing) refetch_.push_back(node);
        recolors_ += missing.size();
    }
    wakeDecode_.notify_all();
    wakeFetch_.notify_all();
}

bool StreamingSet::refetchForRecolor(std::unique_lock<std::mutex>& lock) {
    if (refetch_.empty() || refetchFailed_.second > now()) return false;
    std::vector<NodeRecord> batch;
    std::vector<uint32_t> indices;
    size_t batchBytes = 0;
    while (!refetch_.empty() && batch.size() < kMaxBatchNodes && batchBytes < options_.batchBytes) {
        const uint32_t node = refetch_.back();
        refetch_.pop_back();
        if (!resident_.count(node)) {  // evicted meanwhile: nothing to recolour
            --recolors_;
            continue;
        }
        batch.push_back(nodes()[node]);
        indices.push_back(node);
        batchBytes += batch.back().blockSize;
    }
    if (batch.empty()) return true;
    const uint64_t version = coloringVersion_;
    ++stats_.requestsInFlight;
    lock.unlock();
    auto blobs = source_->blobs(batch);
    lock.lock();
    --stats_.requestsInFlight;
    ++stats_.requests;
    if (version != coloringVersion_) {  // a later setColoring queued its own
        recolors_ -= indices.size();
        return true;
    }
    if (!blobs) {
        failed(&refetchFailed_, source_->describe() + ": blocks to recolour", blobs.status());
        // Tried again after the backoff, unless that stopped the stream.
        if (stats_.gaveUp || stats_.setChanged) recolors_ -= indices.size();
        else refetch_.insert(refetch_.end(), indices.begin(), indices.end());
        return true;
    }
    refetchFailed_ = {0, 0};
    for (size_t i = 0; i < indices.size(); ++i) {
        stats_.bytesDownloaded += (*blobs)[i].size();
        ++stats_.refetched;
        fetched_.push_back({indices[i], std::make_shared<const std::vector<uint8_t>>(std::move((*blobs)[i])), true, true});
    }
    wakeDecode_.notify_all();
    return true;
}

void StreamingSet::adopt(const StreamingSet* donor) {
    {
        std::lock_guard lock(mutex_);
        donor_ = donor;
        if (donor) return;
        // Nodes not yet handed over as the donor's copies are decoded from
        // their kept blocks instead: the donor's copies are going.
        for (auto it = arrived_.begin(); it != arrived_.end();) {
            if (it->surfels || resident_.count(it->index)) {
                ++it;
                continue;
            }
            pending_[it->index] = 1;
            fetched_.push_back({it->index, kept_.at(it->index), false, false, true});
            it = arrived_.erase(it);
        }
    }
    wakeDecode_.notify_all();
}

std::optional<StreamingSet::Kept> StreamingSet::kept(const NodeRecord& record, const std::string& key) const {
    std::lock_guard lock(mutex_);
    const std::optional<uint32_t> index = selector_->find(record.key);
    if (!index) return std::nullopt;
    const NodeRecord& mine = nodes()[*index];
    if (mine.blockCrc != record.blockCrc || mine.blockSize != record.blockSize) return std::nullopt;
    auto it = kept_.find(*index);
    if (it == kept_.end()) return std::nullopt;
    // Resident: handed over in an earlier update(), and not being recoloured.
    const bool drawn = resident_.count(*index) && recolors_ == 0 && sameDecoding(mine, record) && key == decodingKey_;
    return Kept{*index, it->second, drawn};
}

void StreamingSet::forget(uint32_t index) {
    std::lock_guard lock(mutex_);
    auto it = resident_.find(index);
    if (it == resident_.end()) return;
    residentBytes_ -= it->second.bytes;
    resident_.erase(it);
    unkeep(index);
}

void StreamingSet::keep(uint32_t node, Block bytes) {
    auto [it, added] = kept_.emplace(node, bytes);
    if (added) keptBytes_ += bytes->size();
}

void StreamingSet::unkeep(uint32_t node) {
    auto it = kept_.find(node);
    if (it == kept_.end()) return;
    keptBytes_ -= it->second->size();
    kept_.erase(it);
}

void StreamingSet::fail(uint32_t node, const Status& status) {
    pending_.erase(node);
    pendingBytes_ -= residentCost(node);
    failed(&failed_[node], source_->describe() + ": node " + nodes()[node].key.name(), status);
}

void StreamingSet::failed(std::pair<int, double>* attempts, const std::string& what, const Status& status) {
    attempts->first += 1;
    attempts->second = status.isTransient() ? now() + backoffSeconds(attempts->first) : HUGE_VAL;  // never again
    noteFailure(status.message());
    if (!status.isTransient()) {
        if (permanent_.empty()) {
            permanent_ = what + ": failed, not retried (asking again gets the same answer): " + status.message();
            permanentAt_ = now();
        }
    } else if (attempts->first >= std::max(1, options_.maxTries)) {
        stop(what + ": gave up after " + std::to_string(attempts->first) + " tries; the last failed with: " + status.message());
    }
}

void StreamingSet::noteFailure(const std::string& message) {
    ++stats_.failures;
    if (!stats_.gaveUp && !stats_.setChanged) stats_.lastError = message;  // else it says why the stream stopped
    checkDue_ = true;
}

void StreamingSet::stop(const std::string& message) {
    if (stats_.gaveUp || stats_.setChanged) return;
    stats_.gaveUp = true;
    stats_.lastError = message;
    wanted_.clear();
    wantedPages_.clear();
    recolors_ -= refetch_.size();  // the old colours stay drawn
    refetch_.clear();
}

void StreamingSet::addPages() {
    for (auto& [page, records] : pagesFetched_) {
        selector_->addNodes(records);
        pages_[page] = true;
    }
    pagesFetched_.clear();
}

bool StreamingSet::fetchPage(std::unique_lock<std::mutex>& lock) {
    const double t = now();
    for (size_t k = wantedPages_.size(); k-- > 0;) {
        const NodeRecord proxy = nodes()[wantedPages_[k].first];
        const uint32_t page = proxy.childPage;
        auto f = failedPages_.find(page);
        if (pages_.count(page) || (f != failedPages_.end() && f->second.second > t)) continue;
        wantedPages_.erase(wantedPages_.begin() + long(k));
        pages_[page] = false;
        lock.unlock();
        auto records = fetchPageRecords(page, proxy.key);
        lock.lock();
        if (!records) {
            pages_.erase(page);
            failed(&failedPages_[page], source_->describe() + "/hierarchy.bin: page " + std::to_string(page), records.status());
            return true;
        }
        failedPages_.erase(page);
        ++stats_.pages;
        stats_.hierarchyBytes += uint64_t(hierarchy_.pages[page].records) * kRecordSize;
        // Stopped here, before the page joins the tree: update() still hands
        // over and evicts as usual, and its frame reports gaveUp.
        if (Status fits = checkFitsBudget(*records); !fits) {
            stop(fits.message());
            return true;
        }
        pagesFetched_.push_back({page, std::move(*records)});
        return true;
    }
    return false;
}

void StreamingSet::checkForRebuild(std::unique_lock<std::mutex>& lock) {
    checkDue_ = false;
    checking_ = true;
    lastCheck_ = now();
    lock.unlock();
    auto json = source_->file("tileset.json", kMaxTilesetJsonBytes);
    lock.lock();
    checking_ = false;
    if (json && *json != tilesetJson_ && !stats_.setChanged) {
        stats_.setChanged = true;
        stats_.lastError = source_->describe() + ": the tile set changed since it was opened (rebuilt); open it again";
        wanted_.clear();
        wantedPages_.clear();
        recolors_ -= refetch_.size();
        refetch_.clear();
    }
}

void StreamingSet::fetchLoop() {
    std::unique_lock lock(mutex_);
    while (true) {
        wakeFetch_.wait_for(lock, std::chrono::duration<double>(0.05),
                            [&] { return stopping_ || !wanted_.empty() || !wantedPages_.empty() || !refetch_.empty(); });
        if (stopping_) return;
        if (checkDue_ && !checking_ && !stats_.setChanged && (permanentAt_ > lastCheck_ || now() - lastCheck_ > 2.0))
            checkForRebuild(lock);
        // A permanent failure stops the stream once a check begun after it
        // has ended without finding the set changed (a rebuilt set is reported
        // as such instead; a check that cannot read tileset.json stops it too).
        // Meanwhile nothing new starts.
        if (!permanent_.empty() && !checking_ && lastCheck_ >= permanentAt_) stop(permanent_);
        if (!permanent_.empty() && !stats_.gaveUp && !stats_.setChanged) {
            wakeFetch_.wait_for(lock, std::chrono::milliseconds(20));
            continue;
        }
        if (stats_.setChanged || stats_.gaveUp) continue;
        if (fetchPage(lock)) continue;  // pages first: they gate the nodes below them
        if (refetchForRecolor(lock)) continue;
        // The highest-priority wanted nodes that are neither pending nor
        // backing off, as many as one batch takes and the budget admits
        // (every node fits it alone: checkFitsBudget).
        // Nodes the donor holds unchanged go to the decoders at once.
        std::vector<NodeRecord> batch;
        std::vector<uint32_t> indices;
        size_t batchBytes = 0, adopted = 0;
        double t = now(), wait = 0.5;
        for (size_t k = wanted_.size(); k-- > 0 && batch.size() < kMaxBatchNodes && batchBytes < options_.batchBytes;) {
            uint32_t candidate = wanted_[k].first;
            if (pending_.count(candidate) || resident_.count(candidate)) continue;
            auto f = failed_.find(candidate);
            if (f != failed_.end() && f->second.second > t) {
                wait = std::min(wait, f->second.second - t);
                continue;
            }
            size_t cost = residentCost(candidate);
            if (residentBytes_ + pendingBytes_ + cost > options_.memoryBudget) continue;
            wanted_.erase(wanted_.begin() + long(k));
            pending_[candidate] = 1;
            pendingBytes_ += cost;
            if (auto had = donor_ ? donor_->kept(nodes()[candidate], decodingKey_) : std::nullopt) {
                ++stats_.adopted;
                if (!had->sameSurfels) {
                    fetched_.push_back({candidate, std::move(had->block), false, false, true});
                    ++adopted;
                    continue;
                }
                ++stats_.shared;
                keep(candidate, std::move(had->block));  // as a decoded node's (recolouring)
                pending_.erase(candidate);
                failed_.erase(candidate);
                arrived_.push_back({candidate, nullptr, had->index});
                continue;
            }
            batch.push_back(nodes()[candidate]);
            indices.push_back(candidate);
            batchBytes += batch.back().blockSize;
        }
        if (!refetch_.empty()) wait = std::min(wait, refetchFailed_.second - t);  // its backoff
        if (adopted) wakeDecode_.notify_all();
        if (batch.empty() && adopted) continue;
        if (batch.empty()) {
            wakeFetch_.wait_for(lock, std::chrono::duration<double>(std::max(wait, 0.01)));
            continue;
        }
        ++stats_.requestsInFlight;
        lock.unlock();
        double t0 = now();
        auto blobs = source_->blobs(batch);
        double t1 = now();
        lock.lock();
        --stats_.requestsInFlight;
        ++stats_.requests;
        stats_.fetchMs = (t1 - t0) * 1e3;
        if (!blobs) {
            for (uint32_t node : indices) fail(node, blobs.status());
            continue;
        }
        for (size_t i = 0; i < indices.size(); ++i) {
            stats_.bytesDownloaded += (*blobs)[i].size();
            fetched_.push_back({indices[i], std::make_shared<const std::vector<uint8_t>>(std::move((*blobs)[i]))});
        }
        wakeDecode_.notify_all();
    }
}

void StreamingSet::decodeLoop() {
    std::unique_lock lock(mutex_);
    while (true) {
        wakeDecode_.wait(lock, [&] { return stopping_ || !fetched_.empty(); });
        if (stopping_) return;
        Fetched job = std::move(fetched_.front());
        fetched_.pop_front();
        const NodeRecord record = nodes()[job.node];
        const Coloring coloring = options_.coloring;
        const uint64_t version = coloringVersion_;
        lock.unlock();

        double t0 = now();
        Result<BlockData> block = Status::error("");
        const std::vector<uint8_t>& bytes = *job.bytes;
        if (crc32(bytes.data(), bytes.size()) != record.blockCrc)
            block = Status::error(source_->describe() + ": node " + record.key.name() + ": CRC mismatch");
        else
            block = decodeBlock(bytes.data(), bytes.size(), blockExpectation(info_, record));
        std::shared_ptr<SurfelSet> surfels;
        if (block) {
            surfels = std::make_shared<SurfelSet>(emptySurfelSet(info_, coloring));
            appendNode(*surfels, info_, record, *block);
            sortMorton(*surfels);
        }
        double t1 = now();

        lock.lock();
        if (job.recolor) {
            // Superseded by a later setColoring (which queued its own), or
            // evicted meanwhile: dropped. A kept block decoded before, so a
            // failure here is not the block's; it is reported, not retried.
            // A block fetched again that fails is a failure like any fetch's:
            // the node waits to be fetched again (a permanent failure stops
            // the stream first), still counted, so no update converges on
            // its old colours meanwhile.
            const bool current = version == coloringVersion_ && resident_.count(job.node);
            if (!block && job.refetched && current) {
                failed(&refetchFailed_, source_->describe() + ": node " + record.key.name(), block.status());
                if (stats_.gaveUp || stats_.setChanged) --recolors_;
                else refetch_.push_back(job.node);
                continue;
            }
            if (!block && !stats_.gaveUp && !stats_.setChanged) stats_.lastError = block.status().message();
            if (block && current) {
                arrived_.push_back({job.node, std::move(surfels)});  // counted in recolors_ until handed over
                keep(job.node, job.bytes);  // a refetched block is kept again, within the budget at the next update
            } else
                --recolors_;
            continue;
        }
        if (!block) {
            fail(job.node, block.status());
            continue;
        }
        if (version != coloringVersion_) {  // coloured the old way: again, first
            fetched_.push_front(std::move(job));
            continue;
        }
        keep(job.node, job.bytes);
        pending_.erase(job.node);
        failed_.erase(job.node);
        if (!job.adopted) ++stats_.nodesFetched;
        stats_.decodeMs = (t1 - t0) * 1e3;
        arrived_.push_back({job.node, std::move(surfels)});
    }
}

}  // namespace surfcast
