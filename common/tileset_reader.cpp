#include "tileset_reader.h"

#include <algorithm>
#include <atomic>
#include <future>
#include <span>
#include <thread>

#include <cmath>
#include <filesystem>
#include <map>
#include <sstream>

#include "crc32.h"

namespace surfcast {

Result<TilesetReader> TilesetReader::open(std::unique_ptr<TileSource> source) {
    TilesetReader r;
    r.source_ = std::move(source);
    const std::string where = r.source_->describe();
    auto json = r.source_->file("tileset.json", kMaxTilesetJsonBytes);
    if (!json) return json.status();
    auto info = readTilesetJson(std::string(json->begin(), json->end()), where + "/tileset.json");
    if (!info) return info.status();
    r.info_ = *info;
    r.source_->setBlocksLayout(BlocksLayout(blocksPartsOf(r.info_)));
    auto hierarchy = r.source_->file(r.info_.hierarchyFile, r.info_.hierarchyBytes);
    if (!hierarchy) return hierarchy.status();
    auto nodes = readHierarchyOf(r.info_, *hierarchy, where + "/" + r.info_.hierarchyFile);
    if (!nodes) return nodes.status();
    r.nodes_ = std::move(*nodes);
    return r;
}

Result<TilesetReader> TilesetReader::open(const std::string& folder) {
    if (isUrl(folder)) return Status::error(folder + ": a URL, where a local folder is wanted");
    auto r = open(openFolderSource(folder));
    if (!r) return r;
    // A folder's block files must hold what tileset.json says (a URL's
    // ranges are checked as they arrive). blocks.bin may hold more: bytes an
    // update killed before version 3 appended (docs/FORMAT.md, "Updates in place").
    for (const BlocksPart& part : blocksPartsOf(r->info())) {
        std::error_code error;
        const std::string path = folder + "/" + part.file;
        const uint64_t size = std::filesystem::file_size(path, error);
        if (error) return Status::error(path + ": " + error.message());
        if (size < part.bytes)
            return Status::error(path + ": " + std::to_string(size) + " bytes, tileset.json says " + std::to_string(part.bytes));
    }
    return r;
}

BlockExpectation blockExpectation(const TilesetInfo& info, const NodeRecord& node) {
    BlockExpectation e;
    e.codec = info.blockCodec;
    e.colorBits = info.colorBits;
    e.normals = true;
    e.weights = info.weights != "none";
    e.radii = (node.flags & kFlagHasRadius) != 0;
    e.edgeWeights = (node.flags & kFlagEdgeWeights) != 0;
    e.points = node.surfelCount;
    // Every attribute past the fixed ones sits in every block, in the order
    // tileset.json lists them.
    for (const AttributeInfo& a : info.attributes)
        if (std::find(std::begin(kFixedAttributes), std::end(kFixedAttributes), a.name) == std::end(kFixedAttributes)) {
            e.extra.push_back(a.name);
            e.extraBits.push_back(scalarBits(a.type));
        }
    return e;
}

BlockExpectation TilesetReader::expectation(const NodeRecord& node) const { return blockExpectation(info_, node); }

Result<std::vector<uint8_t>> TilesetReader::readBlockBytes(const NodeRecord& node) const {
    auto bytes = source_->blocks(node.blockOffset, node.blockSize);
    if (!bytes) return Status::error("node " + node.key.name() + ": " + bytes.status().message());
    if (crc32(bytes->data(), bytes->size()) != node.blockCrc)
        return Status::error(describe() + ": node " + node.key.name() + " at byte " +
                             std::to_string(node.blockOffset) + ": CRC mismatch");
    return bytes;
}

Result<std::vector<std::vector<uint8_t>>> TilesetReader::readBlocksBytes(const std::vector<NodeRecord>& nodes) const {
    auto blobs = source_->blobs(nodes);
    if (!blobs) return blobs.status();
    for (size_t i = 0; i < nodes.size(); ++i)
        if ((*blobs)[i].size() != nodes[i].blockSize || crc32((*blobs)[i].data(), (*blobs)[i].size()) != nodes[i].blockCrc)
            return Status::error(describe() + ": node " + nodes[i].key.name() + " at byte " + std::to_string(nodes[i].blockOffset) +
                                 ": CRC mismatch");
    return blobs;
}

Result<BlockData> TilesetReader::readBlock(const NodeRecord& node, bool scalars) const {
    auto bytes = readBlockBytes(node);
    if (!bytes) return bytes.status();
    return decoded(node, *bytes, scalars);
}

Status TilesetReader::forEachBlock(const std::vector<NodeRecord>& nodes, bool scalars,
                                   const std::function<Status(const NodeRecord&, BlockData&)>& visit) const {
    return forEachBlockInOrder(
        nodes, scalars, 1, [&](size_t, const NodeRecord& n, BlockData& block) { return visit(n, block); },
        [](size_t) { return Status{}; });
}

Status TilesetReader::forEachBlockInOrder(const std::vector<NodeRecord>& nodes, bool scalars, int threads,
                                          const std::function<Status(size_t, const NodeRecord&, BlockData&)>& prepare,
                                          const std::function<Status(size_t)>& consume) const {
    constexpr uint64_t kBatchBytes = 16ull << 20;
    constexpr size_t kPerThread = 4;  // blocks a thread prepares before the group is consumed
    std::vector<size_t> starts;
    for (size_t first = 0; first < nodes.size();) {
        starts.push_back(first);
        uint64_t bytes = 0;
        do bytes += nodes[first++].blockSize;
        while (first < nodes.size() && bytes + nodes[first].blockSize <= kBatchBytes);
    }
    starts.push_back(nodes.size());
    // The next batch's blobs are read while one is decoded.
    auto fetch = [&](size_t b) {
        return std::async(std::launch::async, [this, batch = std::vector<NodeRecord>(nodes.begin() + long(starts[b]),
                                                                                  nodes.begin() + long(starts[b + 1]))] {
            return readBlocksBytes(batch);
        });
    };
    std::future<Result<std::vector<std::vector<uint8_t>>>> ahead;
    if (!nodes.empty()) ahead = fetch(0);
    for (size_t b = 0; b + 1 < starts.size(); ++b) {
        const size_t first = starts[b];
        const std::span<const NodeRecord> batch(nodes.data() + first, starts[b + 1] - first);
        auto blobs = ahead.get();
        if (!blobs) return blobs.status();
        if (b + 2 < starts.size()) ahead = fetch(b + 1);
        const size_t group = kPerThread * size_t(std::max(threads, 1));
        for (size_t g = 0; g < batch.size(); g += group) {
            const size_t n = std::min(group, batch.size() - g);
            std::vector<Status> results(n);
            std::atomic<size_t> next{0};
            std::atomic<bool> failed{false};
            auto work = [&] {
                for (size_t i; !failed && (i = next++) < n;) {
                    auto block = decoded(batch[g + i], (*blobs)[g + i], scalars);
                    std::vector<uint8_t>().swap((*blobs)[g + i]);
                    results[i] = block ? prepare(first + g + i, batch[g + i], *block) : block.status();
                    if (!results[i].ok()) failed = true;
                }
            };
            std::vector<std::thread> helpers;
            for (int t = 1; t < threads && size_t(t) < n; ++t) helpers.emplace_back(work);
            work();
            for (std::thread& t : helpers) t.join();
            for (size_t i = 0; i < n; ++i) {
                SC_TRY(results[i]);
                SC_TRY(consume(first + g + i));
            }
        }
    }
    return {};
}

Result<BlockData> TilesetReader::decoded(const NodeRecord& node, const std::vector<uint8_t>& bytes, bool scalars) const {
    BlockExpectation e = expectation(node);
    e.scalars = scalars;
    auto block = decodeBlock(bytes.data(), bytes.size(), e);
    if (!block) return Status::error(describe() + ": node " + node.key.name() + ": " + block.status().message());
    if (block->size() != node.surfelCount)
        return Status::error(describe() + ": node " + node.key.name() + " decodes to " +
                             std::to_string(block->size()) + " surfels, hierarchy says " + std::to_string(node.surfelCount));
    return block;
}

double positionStep(const TilesetInfo& info, const NodeRecord& node) {
    return nodeEdge(info, node.key.level) / double((uint64_t(1) << node.positionBits) - 1);
}

Vec3d quantizedPosition(const TilesetInfo& info, const NodeRecord& node, const uint32_t q[3]) {
    return nodeMin(info, node.key) + Vec3d{double(q[0]), double(q[1]), double(q[2])} * positionStep(info, node);
}

Vec3d surfelPosition(const TilesetInfo& info, const NodeRecord& node, const BlockData& block, size_t i) {
    return quantizedPosition(info, node, &block.positions[3 * i]);
}

Vec3d TilesetReader::position(const NodeRecord& node, const BlockData& block, size_t i) const {
    return surfelPosition(info_, node, block, i);
}

Result<std::string> verifyTileset(const TilesetReader& reader) {
    std::map<int, std::pair<uint64_t, uint64_t>> perLevel;  // level -> nodes, surfels
    uint64_t surfels = 0;
    for (const NodeRecord& n : reader.nodes()) {
        auto block = reader.readBlock(n);
        if (!block) return block.status();
        perLevel[n.key.level].first++;
        perLevel[n.key.level].second += n.surfelCount;
        surfels += n.surfelCount;
    }
    const TilesetInfo& info = reader.info();
    if (surfels != info.surfels || reader.nodes().size() != info.nodes)
        return Status::error(reader.describe() + ": node or surfel totals differ from tileset.json");
    std::ostringstream out;
    out << reader.describe() << ": " << info.inputPoints << " input points, " << info.surfels << " surfels in " << info.nodes
        << " nodes, " << info.levels << " levels\n";
    out << "  root min (" << info.rootMin.x << ", " << info.rootMin.y << ", " << info.rootMin.z << "), edge "
        << info.rootEdge << "\n  attributes:";
    for (const auto& a : info.attributes) out << " " << a.name << "(" << a.type << "x" << a.components << ")";
    out << "\n  normals: " << info.normalSource << ", weights: " << info.weights << "\n";
    if (!info.inputs.empty()) {
        out << "  inputs (the \"input\" attribute's values):";
        for (size_t i = 0; i < info.inputs.size(); ++i) out << (i ? ", " : " ") << i << " " << info.inputs[i];
        out << "\n";
    }
    for (auto [level, counts] : perLevel)
        out << "  level " << level << ": " << counts.first << " nodes, " << counts.second << " surfels\n";
    out << "  bytes: hierarchy " << info.hierarchyBytes << ", blocks " << info.blocksBytes << " ("
        << (info.inputPoints ? double(info.blocksBytes) / double(info.inputPoints) : 0.0) << " per input point)\n";
    out << "  all " << info.nodes << " block checksums verified";
    return out.str();
}

}  // namespace surfcast
