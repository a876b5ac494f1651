// The bytes of sets served from an S3 prefix (surfcast-serve s3://BUCKET/PREFIX):
// ranges of their block files fetched from the store off the event loop, on a
// pool of threads, and kept in a cache of bounded size. A cached range is
// keyed by the version that named it (the CRC-32 of its tileset.json), so the
// cache never serves a byte of another version, even of a prefix deleted and
// built again; an update's new version starts with none of its ranges cached.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "object_store.h"
#include "status.h"

namespace surfcast {

class BucketBlocks {
public:
    using Buffer = std::shared_ptr<const std::vector<uint8_t>>;
    struct Range {
        std::string version;  // the version that names it (TilesetSnapshot::range)
        std::string key;      // the object's key in the bucket
        uint64_t offset = 0, size = 0;
        std::optional<uint32_t> crc;  // a node's block: checked before it is kept or served
        std::string id() const;  // the cache's key: every field, the check included
    };
    struct Counts {
        uint64_t hits = 0, misses = 0, bytesFetched = 0, cachedBytes = 0;
    };

    // `cacheBytes`: what the cache may hold (0: nothing is kept); `threads`:
    // fetches at once; `inFlightBytes`: the most bytes being fetched at once
    // (fetch refuses more).
    BucketBlocks(std::shared_ptr<ObjectStore> store, std::string bucket, uint64_t cacheBytes, int threads, uint64_t inFlightBytes);
    ~BucketBlocks();  // waits for the fetches in flight
    BucketBlocks(const BucketBlocks&) = delete;
    BucketBlocks& operator=(const BucketBlocks&) = delete;

    // The range where the cache holds it (null otherwise); counts a hit or a miss.
    Buffer cached(const Range& range);
    // Fetches `ranges` from the store, all at once on the pool, keeps them in
    // the cache, and calls `done` on a pool thread with them in order, or with
    // the first error (naming the object; a block whose CRC differs is one).
    // False, with nothing queued, where their bytes would take the bytes in
    // flight past the budget (the server answers 503).
    bool fetch(std::vector<Range> ranges, std::function<void(Result<std::vector<Buffer>>)> done);
    // The same, waiting for the bytes (a thread of its own: an export's).
    Result<std::vector<uint8_t>> read(const Range& range);

    ObjectStore& store() { return *store_; }
    const std::string& bucket() const { return bucket_; }
    Counts counts() const;

private:
    Result<Buffer> get(const Range& range);
    void keep(const std::string& id, const Buffer& bytes);
    void work();

    std::shared_ptr<ObjectStore> store_;
    std::string bucket_;
    uint64_t cacheBytes_, inFlightBudget_;
    uint64_t inFlight_ = 0;  // under mutex_
    mutable std::mutex mutex_;
    // Least recently used first.
    std::list<std::pair<std::string, Buffer>> lru_;
    std::unordered_map<std::string, std::list<std::pair<std::string, Buffer>>::iterator> index_;
    Counts counts_;
    std::condition_variable wake_;
    std::deque<std::function<void()>> tasks_;
    bool stopping_ = false;
    std::vector<std::thread> threads_;
};

}  // namespace surfcast
