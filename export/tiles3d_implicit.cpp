#include "tiles3d_implicit.h"

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <map>

#include "byte_io.h"
#include "folder_publish.h"

namespace fs = std::filesystem;
using nlohmann::json;

namespace surfcast {

namespace {

constexpr uint32_t kSubtreeMagic = 0x74627573;  // "subt"

// 3D Tiles' Morton index of local coordinates: x in the lowest bit of each triple.
uint64_t morton3(uint32_t x, uint32_t y, uint32_t z, int bits) {
    uint64_t m = 0;
    for (int b = 0; b < bits; ++b)
        m |= uint64_t((x >> b) & 1) << (3 * b) | uint64_t((y >> b) & 1) << (3 * b + 1) | uint64_t((z >> b) & 1) << (3 * b + 2);
    return m;
}

// Tiles of the levels before local level l: (8^l - 1) / 7.
uint64_t levelOffset(int l) { return ((uint64_t(1) << (3 * l)) - 1) / 7; }

// One subtree's bits and tile metadata, as it is filled.
struct Subtree {
    std::vector<uint8_t> tiles, contents, children;  // availability bitstreams
    std::map<uint64_t, const ImplicitTile*> available;  // by bit index: the property table's row order
};

void setBit(std::vector<uint8_t>& bits, uint64_t i) { bits[size_t(i / 8)] |= uint8_t(1u << (i % 8)); }

// The subtree file of `levels` levels: header, JSON, binary (each part padded to 8 bytes).
std::vector<uint8_t> subtreeFile(const Subtree& s, int levels) {
    std::vector<uint8_t> bin;
    json views = json::array();
    const auto addView = [&](const void* data, size_t size) {
        views.push_back({{"buffer", 0}, {"byteOffset", bin.size()}, {"byteLength", size}});
        const auto* p = static_cast<const uint8_t*>(data);
        bin.insert(bin.end(), p, p + size);
        bin.resize((bin.size() + 7) & ~size_t(7), 0);
        return int(views.size() - 1);
    };
    // A bitstream, or a constant where every bit is the same.
    const auto availability = [&](const std::vector<uint8_t>& bits, uint64_t count) -> json {
        bool ones = true, zeros = true;
        for (uint64_t i = 0; i < count; ++i) ((bits[size_t(i / 8)] >> (i % 8)) & 1 ? zeros : ones) = false;
        if (ones || zeros) return {{"constant", ones ? 1 : 0}};
        return {{"bitstream", addView(bits.data(), bits.size())}};
    };
    json j;
    const uint64_t tileBits = levelOffset(levels), childBits = uint64_t(1) << (3 * levels);
    j["tileAvailability"] = availability(s.tiles, tileBits);
    j["contentAvailability"] = json::array({availability(s.contents, tileBits)});
    j["childSubtreeAvailability"] = availability(s.children, childBits);
    std::vector<double> boxes, errors;
    for (const auto& [bit, tile] : s.available) {
        boxes.insert(boxes.end(), tile->box.begin(), tile->box.end());
        errors.push_back(tile->geometricError);
    }
    const int boxView = addView(boxes.data(), boxes.size() * sizeof(double));
    const int errorView = addView(errors.data(), errors.size() * sizeof(double));
    j["propertyTables"] = json::array({{{"class", "tile"},
                                        {"count", s.available.size()},
                                        {"properties", {{"box", {{"values", boxView}}}, {"error", {{"values", errorView}}}}}}});
    j["tileMetadata"] = 0;
    j["buffers"] = json::array({{{"byteLength", bin.size()}}});
    j["bufferViews"] = views;
    std::string text = j.dump();
    text.resize((text.size() + 7) & ~size_t(7), ' ');
    std::vector<uint8_t> out(24 + text.size() + bin.size());
    le::put<uint32_t>(out.data(), kSubtreeMagic), le::put<uint32_t>(out.data() + 4, 1);
    le::put<uint64_t>(out.data() + 8, text.size()), le::put<uint64_t>(out.data() + 16, bin.size());
    std::memcpy(out.data() + 24, text.data(), text.size());
    if (!bin.empty()) std::memcpy(out.data() + 24 + text.size(), bin.data(), bin.size());
    return out;
}

}  // namespace

json implicitTileSchema() {
    return {{"id", kTilesetSchemaId},
            {"classes",
             {{"tile",
               {{"properties",
                 {{"box", {{"type", "SCALAR"}, {"componentType", "FLOAT64"}, {"array", true}, {"count", 12}, {"semantic", "TILE_BOUNDING_BOX"}}},
                  {"error", {{"type", "SCALAR"}, {"componentType", "FLOAT64"}, {"semantic", "TILE_GEOMETRIC_ERROR"}}}}}}}}}};
}

json implicitTiling(int levels, int availableLevels) {
    return {{"subdivisionScheme", "OCTREE"},
            {"subtreeLevels", levels},
            {"availableLevels", availableLevels},
            {"subtrees", {{"uri", "subtrees/{level}-{x}-{y}-{z}.subtree"}}}};
}

Result<uint64_t> writeImplicitSubtrees(const std::vector<ImplicitTile>& tiles, int levels, const std::string& folder) {
    // Bitstreams of a subtree: (8^levels - 1) / 7 tiles, 8^levels child subtrees, bytes rounded up.
    const size_t tileBytes = size_t((levelOffset(levels) + 7) / 8), childBytes = size_t(((uint64_t(1) << (3 * levels)) + 7) / 8);
    std::map<NodeKey, Subtree> subtrees;
    const auto subtree = [&](const NodeKey& root) -> Subtree& {
        Subtree& s = subtrees[root];
        if (s.tiles.empty()) s.tiles.assign(tileBytes, 0), s.contents.assign(tileBytes, 0), s.children.assign(childBytes, 0);
        return s;
    };
    for (const ImplicitTile& t : tiles) {
        const int rootLevel = t.key.level / levels * levels, local = t.key.level - rootLevel;
        const NodeKey root = t.key.ancestor(rootLevel);
        const uint32_t mask = (uint32_t(1) << local) - 1;
        const uint64_t bit = levelOffset(local) + morton3(t.key.x & mask, t.key.y & mask, t.key.z & mask, local);
        Subtree& s = subtree(root);
        setBit(s.tiles, bit);
        if (t.content) setBit(s.contents, bit);
        s.available[bit] = &t;
        if (local == 0 && t.key.level > 0) {  // the root of a child subtree: its parent subtree says so
            const uint32_t m = (uint32_t(1) << levels) - 1;
            setBit(subtree(t.key.ancestor(rootLevel - levels)).children, morton3(t.key.x & m, t.key.y & m, t.key.z & m, levels));
        }
    }
    const fs::path dir = fs::path(folder) / "subtrees";
    std::error_code ec;
    if (!fs::create_directory(dir, ec)) return Status::error(dir.string() + ": cannot create (" + ec.message() + ")");
    uint64_t bytes = 0;
    for (const auto& [root, s] : subtrees) {
        if (!s.available.count(0)) return Status::error("subtree " + root.name() + " lacks its root tile: a node's parent is missing");
        const std::vector<uint8_t> file = subtreeFile(s, levels);
        SC_TRY(writeFileSynced((dir / (root.name() + ".subtree")).string(), file.data(), file.size()));
        bytes += file.size();
    }
    return bytes;
}

}  // namespace surfcast
