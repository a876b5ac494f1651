// Writes a tile set atomically (folder_publish.h): everything goes into a
// hidden folder beside the output, tileset.json last, and the folder is
// swapped into place at the end, so a reader finds the old set or the new
// one, whole (or, where the file system cannot exchange folders, for one
// moment none). The kill-anywhere test in bad_input_test checks this at 20
// random moments.
//
// Blocks are laid out in hierarchy order (hierarchyOrder), whatever order the
// nodes arrive in or the files their blobs come from: the same nodes give the
// same bytes, and siblings sit together in blocks.bin.
#pragma once

#include <cstdio>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "folder_publish.h"
#include "tileset_format.h"

namespace surfcast {

class TilesetWriter {
public:
    // Fails if `output` exists and is neither empty nor a tile set (its
    // tileset.json and hierarchy.bin): it never clobbers other data.
    // `tag`: PublishedFolder::create's, for a second writer of `output` in one process.
    static Result<std::unique_ptr<TilesetWriter>> create(const std::string& output, const std::string& tag = "");
    ~TilesetWriter();  // removes the partial folder unless finish() succeeded

    // An update in place of the set in folder `set`, whose tileset.json says
    // `current` (docs/FORMAT.md, "Updates in place"): nodes added with
    // addKeptNodes keep their blocks where they lie in its block files; every
    // other blob goes into a new file, versionedBlocksFile(its CRC), the next
    // part of the blocks' space (no file of the set is written to); finish()
    // writes the hierarchy as versionedHierarchyFile(its CRC) and then switches
    // tileset.json with one rename, so a reader sees the old set or the new
    // one. The previous version's hierarchy stays for clients that opened it;
    // older ones go. finish() fails before it writes, naming the set, where
    // the set's tileset.json no longer names `current`'s hierarchy and
    // blocks' bytes (another writer replaced the set meanwhile).
    // A blob built again with the same bytes as the current node of its key
    // (`currentNodes`, whose blobs `currentBlobs` reads, several at once:
    // from the folder, or from the store a folder of the set's metadata
    // mirrors) keeps that node's place too; where they cannot be read,
    // finish() fails.
    using CurrentBlobs = std::function<Result<std::vector<std::vector<uint8_t>>>(const std::vector<NodeRecord>&)>;
    static Result<std::unique_ptr<TilesetWriter>> update(const std::string& set, const TilesetInfo& current,
                                                         const std::vector<NodeRecord>& currentNodes, CurrentBlobs currentBlobs);

    // Thread-safe: appends a node's blob to a temporary file and keeps the
    // record with its size and CRC.
    Status addNode(NodeRecord record, const std::vector<uint8_t>& blob);
    // Thread-safe: nodes whose blobs already lie in the file `blocks` (of
    // `bytes` bytes, checked here), at their records' offsets, sizes and
    // CRCs; finish() copies them, checking each CRC. The file stays until then.
    Status addPlacedNodes(const std::string& blocks, uint64_t bytes, const std::vector<NodeRecord>& records);

    // An update's nodes whose blobs stay where they are in the set's blocks.bin
    // (records as the current hierarchy holds them).
    Status addKeptNodes(const std::vector<NodeRecord>& records);
    // An update's nodes built again that hold what the current nodes of their
    // keys hold (the update knows nothing reached them; `built` gives their
    // keys, children and surfel counts, which must be the current nodes'):
    // those nodes stay, record and place.
    Status keepCurrentNodes(const std::vector<NodeRecord>& built);
    // The build record (a plan.bin, stages.h) the set keeps for updates:
    // the file at `path` is moved in as buildRecordFile(the hierarchy's name).
    void setBuildRecord(const std::string& path) { record_ = path; }

    // blocks.bin in hierarchy order (the records' offsets filled in), then
    // hierarchy.bin, then tileset.json, then the exchange. `info` gets the
    // byte counts and checksums filled in.
    Status finish(TilesetInfo& info);

    uint64_t blockBytes() const { return blocksBytes_; }
    const std::string& partialDir() const { return partial_; }

private:
    TilesetWriter() = default;
    Status finishUpdate(TilesetInfo& info);
    // Reads record i's blob from where it arrived (checking a placed blob's CRC).
    Status readBlob(size_t i, std::map<uint32_t, int>& open, std::vector<uint8_t>& blob);
    std::unique_ptr<PublishedFolder> folder_;
    std::string partial_;           // folder_'s path
    std::FILE* blocks_ = nullptr;   // addNode's blobs in arrival order (blocks.unordered)
    uint64_t blocksBytes_ = 0;      // every node's blob
    uint64_t ownBytes_ = 0;         // those in blocks_
    std::vector<NodeRecord> records_;
    std::vector<uint32_t> sources_;      // per record: its blob's file in placed_, or kOwnBlocks
    std::vector<std::string> placed_;    // files of addPlacedNodes
    static constexpr uint32_t kOwnBlocks = ~0u;
    static constexpr uint32_t kKept = ~1u;  // an update's node whose blob stays in place
    std::string set_;          // an update's set folder; empty for a new set
    TilesetInfo current_;      // an update's tileset.json before it
    std::map<NodeKey, NodeRecord> currentNodes_;  // and its nodes
    CurrentBlobs currentBlobs_;                   // which reads their blobs
    std::string record_;       // the build record to publish, if any
    std::mutex mutex_;
};

}  // namespace surfcast
