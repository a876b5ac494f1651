#include "bucket_blocks.h"

#include <atomic>

#include "crc32.h"

namespace surfcast {

std::string BucketBlocks::Range::id() const {
    return version + '\n' + key + '\n' + std::to_string(offset) + '\n' + std::to_string(size) + '\n' + (crc ? std::to_string(*crc) : "-");
}

BucketBlocks::BucketBlocks(std::shared_ptr<ObjectStore> store, std::string bucket, uint64_t cacheBytes, int threads, uint64_t inFlightBytes)
    : store_(std::move(store)), bucket_(std::move(bucket)), cacheBytes_(cacheBytes), inFlightBudget_(inFlightBytes) {
    for (int i = 0; i < std::max(threads, 1); ++i) threads_.emplace_back([this] { work(); });
}

BucketBlocks::~BucketBlocks() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    wake_.notify_all();
    for (std::thread& t : threads_) t.join();
}

void BucketBlocks::work() {
    for (;;) {
        std::function<void()> task;
        {
            std::unique_lock lock(mutex_);
            wake_.wait(lock, [&] { return stopping_ || !tasks_.empty(); });
            if (tasks_.empty()) return;  // stopping, with nothing left to do
            task = std::move(tasks_.front());
            tasks_.pop_front();
        }
        task();
    }
}

BucketBlocks::Buffer BucketBlocks::cached(const Range& range) {
    std::lock_guard lock(mutex_);
    auto it = index_.find(range.id());
    if (it == index_.end()) {
        ++counts_.misses;
        return nullptr;
    }
    ++counts_.hits;
    lru_.splice(lru_.end(), lru_, it->second);  // now the most recently used
    return it->second->second;
}

void BucketBlocks::keep(const std::string& id, const Buffer& bytes) {
    std::lock_guard lock(mutex_);
    counts_.bytesFetched += bytes->size();
    if (bytes->size() > cacheBytes_ || index_.count(id)) return;
    lru_.emplace_back(id, bytes);
    index_[id] = std::prev(lru_.end());
    counts_.cachedBytes += bytes->size();
    while (counts_.cachedBytes > cacheBytes_) {
        counts_.cachedBytes -= lru_.front().second->size();
        index_.erase(lru_.front().first);
        lru_.pop_front();
    }
}

Result<BucketBlocks::Buffer> BucketBlocks::get(const Range& range) {
    auto bytes = store_->getRange({bucket_, range.key}, range.offset, range.size);
    if (!bytes) return bytes.status();
    if (range.crc && crc32(bytes->data(), bytes->size()) != *range.crc)
        return Status::error("s3://" + bucket_ + "/" + range.key + ": bytes " + std::to_string(range.offset) + "+" +
                             std::to_string(range.size) + " differ from the CRC-32 the hierarchy gives (a damaged or replaced object)");
    auto buffer = std::make_shared<const std::vector<uint8_t>>(std::move(*bytes));
    keep(range.id(), buffer);
    return Buffer(buffer);
}

Result<std::vector<uint8_t>> BucketBlocks::read(const Range& range) {
    if (Buffer hit = cached(range)) return *hit;
    auto fetched = get(range);
    if (!fetched) return fetched.status();
    return **fetched;
}

bool BucketBlocks::fetch(std::vector<Range> ranges, std::function<void(Result<std::vector<Buffer>>)> done) {
    struct Job {
        std::vector<Range> ranges;
        std::vector<Buffer> buffers;
        std::function<void(Result<std::vector<Buffer>>)> done;
        std::mutex mutex;
        Status error;
        std::atomic<size_t> left{0};
    };
    auto job = std::make_shared<Job>();
    job->ranges = std::move(ranges);
    job->buffers.resize(job->ranges.size());
    job->done = std::move(done);
    job->left = job->ranges.size();
    if (job->ranges.empty()) {
        job->done(std::vector<Buffer>());
        return true;
    }
    uint64_t bytes = 0;
    for (const Range& r : job->ranges) bytes += r.size;
    {
        std::lock_guard lock(mutex_);
        if (inFlight_ + bytes > inFlightBudget_ && inFlight_ > 0) return false;  // (one request alone always goes)
        inFlight_ += bytes;
        for (size_t i = 0; i < job->ranges.size(); ++i)
            tasks_.push_back([this, job, i, bytes] {
                auto got = get(job->ranges[i]);
                {
                    std::lock_guard lock(job->mutex);
                    if (got) job->buffers[i] = std::move(*got);
                    else if (job->error.ok()) job->error = got.status();
                }
                if (job->left.fetch_sub(1) != 1) return;
                {
                    std::lock_guard lock(mutex_);
                    inFlight_ -= bytes;
                }
                if (!job->error.ok()) job->done(job->error);
                else job->done(std::move(job->buffers));
            });
    }
    wake_.notify_all();
    return true;
}

BucketBlocks::Counts BucketBlocks::counts() const {
    std::lock_guard lock(mutex_);
    return counts_;
}

}  // namespace surfcast
