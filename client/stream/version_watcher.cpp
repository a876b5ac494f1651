#include "version_watcher.h"

#include <chrono>
#include <utility>

#include "http_tile_source.h"

namespace surfcast {

VersionWatcher::VersionWatcher(std::string location, StreamOptions options, std::vector<uint8_t> shown, double intervalSeconds)
    : location_(std::move(location)), options_(std::move(options)), interval_(intervalSeconds), shown_(std::move(shown)),
      thread_([this] { loop(); }) {}

VersionWatcher::~VersionWatcher() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
        for (const auto& source : {polling_, opening_})
            if (source) source->cancel();
    }
    wake_.notify_all();
    thread_.join();
}

std::unique_ptr<StreamingSet> VersionWatcher::take() {
    std::lock_guard lock(mutex_);
    return std::move(ready_);
}

void VersionWatcher::showing(std::vector<uint8_t> shown) {
    std::lock_guard lock(mutex_);
    shown_ = std::move(shown);
    reread_ = true;
}

size_t VersionWatcher::polls() const {
    std::lock_guard lock(mutex_);
    return polls_;
}

std::string VersionWatcher::lastError() const {
    std::lock_guard lock(mutex_);
    return lastError_;
}

void VersionWatcher::loop() {
    // A source of its own, so that polling leaves the shown stream's source
    // (and the version its batches ask for) alone.
    std::shared_ptr<TileSource> source;
    std::string tag;
    std::unique_lock lock(mutex_);
    while (!wake_.wait_for(lock, std::chrono::duration<double>(interval_), [&] { return stopping_; })) {
        ++polls_;
        if (std::exchange(reread_, false)) tag.clear();  // unchanged on the host, yet no longer shown
        lock.unlock();
        Status status;
        std::unique_ptr<StreamingSet> opened;
        if (!source) {
            auto s = openTileSource(location_, options_.http);
            if (s) source = std::move(*s);
            else status = s.status();
            lock.lock();
            polling_ = source;
            if (stopping_ && source) source->cancel();
            lock.unlock();
        }
        std::optional<std::vector<uint8_t>> changed;
        if (source) {
            auto polled = source->changedFile("tileset.json", kMaxTilesetJsonBytes, &tag);
            if (polled) changed = std::move(*polled);
            else status = polled.status();
        }
        lock.lock();
        const bool differs = changed && *changed != shown_;
        lock.unlock();
        if (differs) {
            // The version opened is whatever tileset.json names by then.
            auto s = openTileSource(location_, options_.http);
            if (s) {
                std::shared_ptr<TileSource> reading = std::move(*s);
                lock.lock();
                opening_ = reading;
                if (stopping_) reading->cancel();
                lock.unlock();
                auto set = StreamingSet::open(reading, location_, options_);
                if (set) opened = std::move(*set);
                else status = set.status();
                lock.lock();
                opening_.reset();
                lock.unlock();
            } else {
                status = s.status();
            }
        }
        lock.lock();
        if (!status.ok()) {
            lastError_ = status.message();
            tag.clear();  // read it whole next time, and compare
        } else {
            lastError_.clear();
        }
        if (opened && opened->tilesetJson() != shown_) {
            shown_ = opened->tilesetJson();
            ready_ = std::move(opened);
        }
    }
}

}  // namespace surfcast
