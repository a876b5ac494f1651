// The tile sets under one folder, memory-mapped, as immutable snapshots (or
// under an S3 prefix: openBucket). A
// request takes the current snapshot of its set and serves every byte of its
// response from it; a set rebuilt and renamed over the old one is noticed on
// the next request (the inode of its tileset.json changes) and loaded as a new
// snapshot, while responses in flight keep the old mappings alive. No response
// ever mixes old and new bytes.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <condition_variable>
#include <ctime>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "bucket_blocks.h"
#include "octree_key.h"
#include "status.h"
#include "tile_source.h"
#include "tileset_format.h"

namespace surfcast {

// A read-only mapping of a whole file; empty files map to nothing. Or, for
// a set in a bucket, bytes read from the store, held in memory.
class MappedFile {
public:
    static Result<std::shared_ptr<MappedFile>> openAt(int dirFd, const std::string& name, const std::string& what);
    static std::shared_ptr<MappedFile> fromBytes(std::vector<uint8_t> bytes);
    ~MappedFile();
    const uint8_t* data() const { return data_; }
    uint64_t size() const { return size_; }

private:
    MappedFile() = default;
    const uint8_t* data_ = nullptr;
    uint64_t size_ = 0;
    std::vector<uint8_t> held_;  // fromBytes's; empty: data_ is a mapping
};

struct TilesetSnapshot {
    std::string name;
    TilesetInfo info;
    std::shared_ptr<MappedFile> json, hierarchy;
    // The files of the blocks (blocksPartsOf(info)), mapped, in order; each
    // node's block lies inside one part's declared bytes (checked at load).
    BlocksLayout layout;
    std::vector<std::shared_ptr<MappedFile>> partFiles;
    const uint8_t* block(const NodeRecord& node) const;
    // The mapped file of part `file`, or null where this version has none of
    // that name (or the set is in a bucket).
    const MappedFile* partFile(const std::string& file, uint64_t* declaredBytes) const;
    // The bytes this version declares for part `file`; nullopt where it has none of that name.
    std::optional<uint64_t> partBytes(const std::string& file) const;
    std::unordered_map<NodeKey, NodeRecord, NodeKeyHash> nodes;
    uint32_t version = 0;  // CRC-32 of tileset.json: it covers every block through the hierarchy CRC
    // A set in a bucket: tileset.json and the hierarchy in memory, no part
    // mapped (partFiles empty, block() not to be called); its block files'
    // bytes come from `bucket`, under keyPrefix + the file's name.
    std::shared_ptr<BucketBlocks> bucket;
    std::string keyPrefix, jsonEtag;
    BucketBlocks::Range range(const std::string& file, uint64_t offset, uint64_t size, std::optional<uint32_t> crc = {}) const {
        return {std::to_string(version), keyPrefix + file, offset, size, crc};
    }
    // Identity of the tileset.json it was loaded from.
    dev_t device = 0;
    ino_t inode = 0;
    timespec modified{};
};

// The input points the leaves (kFlagInputPoints) reached by `box` hold (all
// leaves without one): the nodes exportPointsAtMost (laz_export.h) counts,
// from the snapshot's node table. It walks down from the root only into
// nodes whose cube meets the box and stops as soon as the sum passes
// `stopAbove`, so its work is bounded by the box and that limit, never by
// the set's size (the export route refuses with it on the event loop).
uint64_t leafPointsAtMost(const TilesetSnapshot& snapshot, const std::optional<Box3d>& box, uint64_t stopAbove);

// The snapshot's mapped files as a TileSource (for a TilesetReader over it:
// the export route), holding the snapshot while it lives.
std::unique_ptr<TileSource> snapshotSource(std::shared_ptr<const TilesetSnapshot> snapshot);

class TilesetStore {
public:
    // `root` must exist; sets are its direct sub-folders holding tileset.json.
    static Result<std::unique_ptr<TilesetStore>> open(const std::string& root);
    // The sets under s3://BUCKET/PREFIX (each PREFIX/NAME/tileset.json), as
    // the AWS chain reaches them (object_store.h), listed at once (an error
    // where the store refuses) and then every `pollSeconds`: a set whose
    // tileset.json's ETag changed is loaded again, a new one appears, a
    // deleted one goes. Block bytes go through a cache of `cacheBytes`.
    static Result<std::unique_ptr<TilesetStore>> openBucket(const std::string& url, uint64_t cacheBytes, double pollSeconds);
    ~TilesetStore();
    // A bucket's blocks (null for a folder).
    const std::shared_ptr<BucketBlocks>& bucket() const { return bucket_; }

    // Set names: 1-128 of [A-Za-z0-9._-], not starting with '.'. Anything else
    // (traversal, encoded or not, hidden folders) is refused before any disk access.
    static bool validName(const std::string& name);

    // The current snapshot of a set, reloaded if its files were replaced; null
    // with `error` set when there is no such set or it does not load.
    std::shared_ptr<const TilesetSnapshot> get(const std::string& name, std::string* error);
    // The snapshot of set `name` at version `version` (its hierarchy CRC):
    // the current one, or the one it replaced, which clients that opened the
    // set before an update (or a rebuild) still read until they reopen
    // (docs/PROTOCOL.md, "Versions"); null for any other version. Call get()
    // first: it notices a replacement.
    std::shared_ptr<const TilesetSnapshot> pinned(const std::string& name, uint32_t version);
    // Every loadable set, sorted by name.
    std::vector<std::shared_ptr<const TilesetSnapshot>> list();
    // A hierarchy file of set `name` other than its current one (a client
    // holding the tileset.json before an update in place still reads its
    // pages); `file` must pass validHierarchyFile.
    Result<std::shared_ptr<MappedFile>> hierarchyFile(const std::string& name, const std::string& file);

    const std::string& root() const { return root_; }

private:
    TilesetStore() = default;
    Result<std::shared_ptr<TilesetSnapshot>> load(const std::string& name);
    Result<std::shared_ptr<TilesetSnapshot>> loadFromBucket(const std::string& name);
    // Lists the bucket's prefix and loads what changed; an error where the
    // listing fails (a set that fails to load keeps its last snapshot, and
    // says so on stderr).
    Status refresh();
    // Makes `snap` the current snapshot of its set.
    void install(std::shared_ptr<const TilesetSnapshot> snap);

    std::string root_;
    int rootFd_ = -1;
    std::mutex mutex_;
    std::unordered_map<std::string, std::shared_ptr<const TilesetSnapshot>> sets_;
    std::unordered_map<std::string, std::shared_ptr<const TilesetSnapshot>> previous_;  // what each set's current one replaced
    // A bucket's: the sets' prefix ("PREFIX/", or empty), and the thread
    // that lists it every pollSeconds_ until the store is destroyed.
    std::shared_ptr<BucketBlocks> bucket_;
    std::string prefix_;
    double pollSeconds_ = 0;
    std::thread poller_;
    std::condition_variable pollWake_;
    bool stopping_ = false;  // under mutex_
    std::unordered_map<std::string, std::string> loadErrors_;  // per set: the last one said on stderr
};

}  // namespace surfcast
