// Writes a tile set atomically: everything goes into a hidden folder beside the
// output (".NAME.partial-PID"), tileset.json last, and the folder is renamed
// into place at the end. A killed build leaves only the hidden folder, which
// holds no tileset.json and never reads as a tile set.
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

    // Thread-safe: appends a node's blob to blocks.bin and fills the record's
    // offset, size and CRC, then keeps the record.
    Status addNode(NodeRecord record, const std::vector<uint8_t>& blob);

    // hierarchy.bin, then tileset.json, then the rename. `info` gets the byte
    // counts and checksums filled in.
    Status finish(TilesetInfo& info);

    uint64_t blockBytes() const { return blocksBytes_; }
    const std::string& partialDir() const { return partial_; }

private:
    TilesetWriter() = default;
    std::string output_, partial_;
    std::FILE* blocks_ = nullptr;
    uint64_t blocksBytes_ = 0;
    std::vector<NodeRecord> records_;
    std::mutex mutex_;
    bool finished_ = false;
};

}  // namespace surfcast
