// Read a tile set from any TileSource (a local folder, or an http(s) URL
// through net/http_tile_source.h's openTileset): tileset.json and
// hierarchy.bin whole, and blocks on demand. Used by `surfcast-build --info`,
// `surfcast-view` without `--lod`, the weight capture, the bench tools and the tests.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "block_codec.h"
#include "tile_source.h"
#include "tileset_format.h"

namespace surfcast {

class TilesetReader {
public:
    static Result<TilesetReader> open(std::unique_ptr<TileSource> source);
    // A local folder, whose blocks.bin must also be the size tileset.json says.
    static Result<TilesetReader> open(const std::string& folder);

    const TilesetInfo& info() const { return info_; }
    const std::vector<NodeRecord>& nodes() const { return nodes_; }
    BlockExpectation expectation(const NodeRecord& node) const;

    // The node's raw blob, checked against its CRC.
    Result<std::vector<uint8_t>> readBlockBytes(const NodeRecord& node) const;
    // Several nodes' raw blobs, all asked at once (TileSource::blobs), each checked against its CRC.
    Result<std::vector<std::vector<uint8_t>>> readBlocksBytes(const std::vector<NodeRecord>& nodes) const;
    // The node's block decoded (with its scalar attributes where `scalars`),
    // checked against the hierarchy's surfel count; errors name the node.
    Result<BlockData> readBlock(const NodeRecord& node, bool scalars = false) const;
    // Each of `nodes` decoded as readBlock decodes it, in their order, to
    // `visit`; their blobs are asked for in batches of about 16 MiB at once
    // (from a store, one batch's ranges together rather than one at a time),
    // the next batch while one is decoded.
    // Stops at the first error, the visitor's own included.
    Status forEachBlock(const std::vector<NodeRecord>& nodes, bool scalars,
                        const std::function<Status(const NodeRecord&, BlockData&)>& visit) const;
    // As forEachBlock, on `threads` threads: a batch's blocks are decoded and
    // given to `prepare` (with their index in `nodes`) a few per thread at a
    // time, concurrently, and then `consume` runs for each index, in order,
    // on the caller's thread. `prepare` must not throw, may touch only what
    // its index owns, and the block lives only through the call. Stops at the
    // first error (the earliest block's of a group; blocks a thread already
    // took are prepared).
    Status forEachBlockInOrder(const std::vector<NodeRecord>& nodes, bool scalars, int threads,
                               const std::function<Status(size_t, const NodeRecord&, BlockData&)>& prepare,
                               const std::function<Status(size_t)>& consume) const;
    // World-space position of quantized surfel i of a decoded block.
    Vec3d position(const NodeRecord& node, const BlockData& block, size_t i) const;

    // Where blocks come from: the folder's path or the URL (without its query).
    std::string describe() const { return source_->describe(); }

private:
    Result<BlockData> decoded(const NodeRecord& node, const std::vector<uint8_t>& bytes, bool scalars) const;
    TilesetInfo info_;
    std::vector<NodeRecord> nodes_;
    std::shared_ptr<TileSource> source_;
};

// What a node's block carries, and surfel i's world position, from the set's
// metadata alone (for readers of blocks fetched elsewhere, e.g. over HTTP).
BlockExpectation blockExpectation(const TilesetInfo& info, const NodeRecord& node);
Vec3d surfelPosition(const TilesetInfo& info, const NodeRecord& node, const BlockData& block, size_t i);
// A node's quantization step, and the world position of quantized position q.
double positionStep(const TilesetInfo& info, const NodeRecord& node);
Vec3d quantizedPosition(const TilesetInfo& info, const NodeRecord& node, const uint32_t q[3]);

// Verify a tile set: every CRC, every block decodes with the declared
// attributes and count. Returns a summary text on success.
Result<std::string> verifyTileset(const TilesetReader& reader);

}  // namespace surfcast
