#include "streamer.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "crc32.h"
#include "tileset_reader.h"

namespace surfcast {

namespace {
double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
// Retry after 0.1 s, doubling per failure up to 5 s: a restarting server
// comes back without the client hammering it.
double backoffSeconds(int attempts) { return std::min(5.0, 0.1 * std::pow(2.0, attempts - 1)); }
}  // namespace

Result<std::unique_ptr<StreamingSet>> StreamingSet::open(const std::string& location, int connections) {
    std::unique_ptr<StreamingSet> s(new StreamingSet);
    auto source = openTileSource(location);
    if (!source) return source.status();
    s->source_ = std::move(*source);
    auto json = s->source_->file("tileset.json");
    if (!json) return json.status();
    auto info = readTilesetJson(std::string(json->begin(), json->end()), location + "/tileset.json");
    if (!info) return info.status();
    s->info_ = *info;
    auto hierarchy = s->source_->file("hierarchy.bin");
    if (!hierarchy) return hierarchy.status();
    if (hierarchy->size() != s->info_.hierarchyBytes || crc32(hierarchy->data(), hierarchy->size()) != s->info_.hierarchyCrc)
        return Status::error(location + "/hierarchy.bin: size or CRC differs from tileset.json");
    auto nodes = readHierarchy(*hierarchy, location + "/hierarchy.bin");
    if (!nodes) return nodes.status();
    s->selector_ = std::make_unique<LodSelector>(s->info_, std::move(*nodes));
    for (int i = 0; i < std::max(1, connections); ++i) s->workers_.emplace_back([p = s.get()] { p->work(); });
    return s;
}

StreamingSet::~StreamingSet() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    wake_.notify_all();
    for (auto& t : workers_) t.join();
}

std::vector<SelectedNode> StreamingSet::update(const Camera& camera, int width, int height, const LodParams& params,
                                               LodStats* lod, bool* converged) {
    LodStats local;
    LodStats& st = lod ? *lod : local;
    std::vector<SelectedNode> selected;
    {
        std::lock_guard lock(mutex_);
        selected = selector_->select(camera, width, height, params,
                                     [&](uint32_t i) { return resident_.count(i) != 0; }, &st);
        // Requests the view no longer needs are dropped (cancelled before they
        // start; a fetch in flight completes and stays cached).
        wanted_.clear();
        for (const auto& [node, priority] : st.missing)
            if (!inFlight_.count(node)) wanted_.push_back({node, priority});
        std::stable_sort(wanted_.begin(), wanted_.end(), [](auto& a, auto& b) { return a.second < b.second; });
        stats_.queued = wanted_.size();
        *converged = st.missing.empty();
    }
    wake_.notify_all();
    return selected;
}

std::shared_ptr<const BlockData> StreamingSet::block(uint32_t index) const {
    std::lock_guard lock(mutex_);
    auto it = resident_.find(index);
    return it == resident_.end() ? nullptr : it->second;
}

StreamStats StreamingSet::stats() const {
    std::lock_guard lock(mutex_);
    StreamStats s = stats_;
    s.inFlight = inFlight_.size();
    s.resident = resident_.size();
    return s;
}

void StreamingSet::work() {
    std::unique_lock lock(mutex_);
    while (true) {
        // The highest-priority wanted node that is not in flight and not backing off.
        uint32_t node = UINT32_MAX;
        double wait = 0.5;
        wake_.wait_for(lock, std::chrono::duration<double>(0.05), [&] { return stopping_ || !wanted_.empty(); });
        if (stopping_) return;
        double t = now();
        for (size_t k = wanted_.size(); k-- > 0;) {
            uint32_t candidate = wanted_[k].first;
            if (inFlight_.count(candidate) || resident_.count(candidate)) continue;
            auto f = failed_.find(candidate);
            if (f != failed_.end() && f->second.second > t) {
                wait = std::min(wait, f->second.second - t);
                continue;
            }
            node = candidate;
            wanted_.erase(wanted_.begin() + long(k));
            break;
        }
        if (node == UINT32_MAX) {
            wake_.wait_for(lock, std::chrono::duration<double>(std::max(wait, 0.01)));
            continue;
        }
        inFlight_[node] = 1;
        const NodeRecord record = selector_->nodes()[node];
        lock.unlock();

        double t0 = now();
        auto bytes = source_->blocks(record.blockOffset, record.blockSize);
        double t1 = now();
        Result<BlockData> block = Status::error("");
        if (bytes) {
            if (crc32(bytes->data(), bytes->size()) != record.blockCrc)
                block = Status::error(source_->describe() + ": node " + record.key.name() + ": CRC mismatch");
            else
                block = decodeBlock(bytes->data(), bytes->size(), blockExpectation(info_, record));
        } else {
            block = bytes.status();
        }
        double t2 = now();

        lock.lock();
        inFlight_.erase(node);
        ++stats_.requests;
        if (bytes) stats_.bytesDownloaded += bytes->size();
        if (block) {
            resident_[node] = std::make_shared<const BlockData>(std::move(*block));
            failed_.erase(node);
            stats_.fetchMs = (t1 - t0) * 1e3;
            stats_.decodeMs = (t2 - t1) * 1e3;
        } else {
            auto& f = failed_[node];
            f.first += 1;
            f.second = now() + backoffSeconds(f.first);
            ++stats_.failures;
            stats_.lastError = block.status().message();
        }
    }
}

}  // namespace surfcast
