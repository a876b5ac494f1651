#include "reweight.h"

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "tileset_writer.h"

namespace surfcast {

std::string ReweightSummary::text() const {
    char buf[256];
    std::snprintf(buf, sizeof(buf),
                  "nodes: %zu, blocks %llu bytes; capture: %zu of %zu surfels seen (%zu with edge weights) in %zu "
                  "renders, %.2f s; total %.2f s\n",
                  nodes, (unsigned long long)blocksBytes, capture.seen, capture.surfels, capture.edges, capture.renders,
                  capture.seconds, seconds);
    return buf;
}

Result<ReweightSummary> reweightTileset(const std::string& dir, const ReweightOptions& options) {
    auto start = std::chrono::steady_clock::now();
    ReweightSummary summary;
    auto reader = TilesetReader::open(dir);
    if (!reader) return reader.status();
    // Blocks are decoded and re-encoded: an attribute this reader does not know
    // (a newer writer's) would be dropped from them, so such a set is refused.
    for (const std::string& name : blockExpectation(reader->info(), NodeRecord{}).extra)
        if (std::find(std::begin(kLidarAttributes), std::end(kLidarAttributes), name) == std::end(kLidarAttributes))
            return Status::error(dir + ": attribute '" + name + "' is unknown to this version; its blocks cannot be rewritten");
    const auto& nodes = reader->nodes();
    std::vector<BlockData> blocks;
    blocks.reserve(nodes.size());
    for (const NodeRecord& node : nodes) {
        auto b = reader->readBlock(node);
        if (!b) return b.status();
        blocks.push_back(std::move(*b));
    }

    std::vector<std::vector<float>> weights(nodes.size()), edgeWeights(nodes.size());
    if (options.method == WeightMethod::Capture && !nodes.empty()) {
        auto ctx = gpu::createContext({options.device, options.validation, {}, false});
        if (!ctx) return ctx.status();
        auto captured = captureWeights(**ctx, *reader, blocks, options.capture, &summary.capture);
        int errors = (*ctx)->validationErrors.load();
        gpu::destroyContext(*ctx);
        if (!captured) return captured.status();
        if (errors > 0) return Status::error(std::to_string(errors) + " Vulkan validation error(s) during capture");
        weights = std::move(captured->weights);
        edgeWeights = std::move(captured->edgeWeights);
    }

    auto writer = TilesetWriter::create(dir);
    if (!writer) return writer.status();
    TilesetInfo info = reader->info();
    // Blocks are re-encoded with the set's own quantization, which tileset.json
    // keeps declaring: only the weights change.
    const int normalBits = info.normalBits(BlockCodecOptions{}.normalBits);
    for (size_t n = 0; n < nodes.size(); ++n) {
        BlockData& b = blocks[n];
        b.weights = std::move(weights[n]);
        b.edgeWeights = std::move(edgeWeights[n]);
        NodeRecord record = nodes[n];
        record.flags = uint16_t((record.flags & ~kFlagEdgeWeights) | (b.edgeWeights.empty() ? 0 : kFlagEdgeWeights));
        BlockCodecOptions codec;
        codec.codec = info.blockCodec;
        codec.positionBits = nodes[n].positionBits;
        codec.colorBits = info.colorBits ? info.colorBits : 8;
        codec.normalBits = normalBits;
        auto blob = encodeBlock(b, codec);
        if (!blob) return Status::error("node " + nodes[n].key.name() + ": " + blob.status().message());
        SC_TRY(writer.value()->addNode(record, *blob));
    }
    // The attribute list in block order (FORMAT.md): weight after colour, before
    // radius; edge_weight (only in nodes flagged EDGE_WEIGHTS, like radius)
    // after radius; the LiDAR attributes last.
    std::vector<AttributeInfo> attributes;
    for (const auto& a : info.attributes) {
        if (a.name == "weight" || a.name == "edge_weight") continue;
        if (a.name == "radius" && options.method == WeightMethod::Capture)
            attributes.push_back({"weight", "float32", 1, BlockCodecOptions{}.weightBits});
        attributes.push_back(a);
        if (a.name == "radius" && options.method == WeightMethod::Capture)
            attributes.push_back({"edge_weight", "float32", 4, BlockCodecOptions{}.edgeWeightBits});
    }
    info.attributes = attributes;
    info.weights = options.method == WeightMethod::Capture ? "captured" : "none";
    SC_TRY(writer.value()->finish(info));
    summary.nodes = nodes.size();
    summary.blocksBytes = info.blocksBytes;
    summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return summary;
}

}  // namespace surfcast
