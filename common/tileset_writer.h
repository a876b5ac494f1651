// Writes a tile set atomically: everything goes into a hidden folder beside the
// output (".NAME.partial-PID"), tileset.json last, and the folder is renamed
// into place at the end. An existing set at the output is exchanged with the
// new one in one step (renameat2 RENAME_EXCHANGE), so that at no moment does
// no set exist there; where the file system cannot exchange, the old set is
// moved aside (".NAME.old-PID") and the new one moved in. A writer killed at
// any moment leaves the output holding the old set or the new one, whole, or
// (in the fallback's one gap, or a first build) no set; and hidden folders
// beside it, which the next writer into the same output removes (an old set
// moved aside goes back if the output is empty). The kill-anywhere test in
// bad_input_test checks this at 20 random moments.
//
// Blocks are laid out in hierarchy order (hierarchyOrder), whatever order the
// nodes arrive in or the files their blobs come from: the same nodes give the
// same bytes, and siblings sit together in blocks.bin.
#pragma once

#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "tileset_format.h"

namespace surfcast {

class TilesetWriter {
public:
    // Fails if `output` exists and is not a tile set (never clobbers other data).
    static Result<std::unique_ptr<TilesetWriter>> create(const std::string& output);
    ~TilesetWriter();  // removes the partial folder unless finish() succeeded

    // Thread-safe: appends a node's blob to a temporary file and keeps the
    // record with its size and CRC.
    Status addNode(NodeRecord record, const std::vector<uint8_t>& blob);
    // Thread-safe: nodes whose blobs already lie in the file `blocks` (of
    // `bytes` bytes, checked here), at their records' offsets, sizes and
    // CRCs; finish() copies them, checking each CRC. The file stays until then.
    Status addPlacedNodes(const std::string& blocks, uint64_t bytes, const std::vector<NodeRecord>& records);

    // blocks.bin in hierarchy order (the records' offsets filled in), then
    // hierarchy.bin, then tileset.json, then the exchange. `info` gets the
    // byte counts and checksums filled in.
    Status finish(TilesetInfo& info);

    uint64_t blockBytes() const { return blocksBytes_; }
    const std::string& partialDir() const { return partial_; }

private:
    TilesetWriter() = default;
    std::string output_, partial_;
    std::FILE* blocks_ = nullptr;   // addNode's blobs in arrival order (blocks.unordered)
    uint64_t blocksBytes_ = 0;      // every node's blob
    uint64_t ownBytes_ = 0;         // those in blocks_
    std::vector<NodeRecord> records_;
    std::vector<uint32_t> sources_;      // per record: its blob's file in placed_, or kOwnBlocks
    std::vector<std::string> placed_;    // files of addPlacedNodes
    static constexpr uint32_t kOwnBlocks = ~0u;
    std::mutex mutex_;
    bool finished_ = false;
};

}  // namespace surfcast
