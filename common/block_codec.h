// Node blocks (docs/FORMAT.md, "blocks.bin"). The only file that includes
// Draco. Draco's kd-tree encoder reorders points, so every per-surfel value
// travels in the kd-tree's decoded order, never as a side array of the input's.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "status.h"

namespace surfcast {

// How a set's blocks are coded (tileset.json `blocks.codec`).
enum class BlockCodec {
    // "draco": one kd-tree point cloud holding every attribute.
    Draco,
    // "draco-columns": the positions alone in a kd-tree point cloud, then the
    // other attributes, column by column in the first's decoded order, in a
    // sequentially coded one (delta and entropy coding per column): the
    // kd-tree's cost grows with the dimensions it holds (bench/BENCHMARKS.md,
    // "Block coding").
    DracoColumns,
};
const char* blockCodecName(BlockCodec codec);
std::optional<BlockCodec> parseBlockCodec(const std::string& name);

// A scalar field's quantized values (FORMAT.md, "Scalar attributes"): 1 per surfel.
struct ScalarAttribute {
    std::string name;  // as tileset.json lists it (decoding fills it)
    int bits = 32;     // the values' width: stored as uint8, uint16 or uint32 (scalarType; draco-columns: uint32 as two uint16)
    std::vector<uint32_t> values;
};

// The tileset.json type of a scalar attribute of `bits` bits.
inline const char* scalarType(int bits) { return bits <= 8 ? "uint8" : bits <= 16 ? "uint16" : "uint32"; }
// The width BlockExpectation::extraBits takes for an attribute of tileset.json
// type `type`: 32 for uint32 (two columns in draco-columns), 16, else 8.
inline int scalarBits(const std::string& type) { return type == "uint32" ? 32 : type == "uint16" ? 16 : 8; }

// What a block carries. Attributes with empty vectors are absent.
struct BlockData {
    std::vector<uint32_t> positions;  // 3 per surfel: quantized in the node box, [0, 2^bits-1]
    std::vector<float> normals;       // 3 per surfel, unit length (world space)
    std::vector<uint16_t> colors;     // 3 per surfel, in [0, 2^colorBits-1]
    std::vector<float> weights;       // 1 per surfel: normalization weight s_k
    std::vector<float> radii;         // 1 per surfel: own h, world units (irregular nodes only)
    std::vector<float> edgeWeights;   // 4 per surfel: weight / s_k at the tangent points
                                      // +r s, -r s, +r t, -r t (nodes at the model's edges only)
    // LiDAR attributes (docs/FORMAT.md, "LiDAR attributes"), 1 per surfel each.
    std::vector<uint16_t> intensity;
    std::vector<uint8_t> classification;
    std::vector<uint8_t> returnNumber;
    std::vector<uint8_t> numberOfReturns;
    // Opacity, 255 = opaque (docs/FORMAT.md, "Opacity"): only in translucent sets.
    std::vector<uint8_t> opacity;
    // Scalar attributes, after the LiDAR ones, in tileset.json's order (decoded
    // only with BlockExpectation::scalars).
    std::vector<ScalarAttribute> scalars;

    size_t size() const { return positions.size() / 3; }
};

struct BlockCodecOptions {
    BlockCodec codec = BlockCodec::DracoColumns;
    int positionBits = 16;  // bits the positions occupy (for Draco's integer coder)
    int colorBits = 8;      // 8 or 16: stored as uint8 or uint16
    // Draco's quantization of normals: bits per component (draco) or of each
    // of the two octahedral coordinates (draco-columns).
    int normalBits = 8;
    int weightBits = 12;    // per weight
    int radiusBits = 8;     // per radius
    int edgeWeightBits = 8; // per edge-weight ratio
};

Result<std::vector<uint8_t>> encodeBlock(const BlockData& block, const BlockCodecOptions& options);
// tileset.json names of the attributes the fixed layout places (FORMAT.md,
// "blocks.bin"); every other listed attribute follows them in every block.
inline constexpr const char* kFixedAttributes[] = {"position", "normal", "color", "weight", "radius", "edge_weight"};

// The LiDAR attributes a block can carry: tileset.json names, in block order
// after the fixed attributes (each block stores those its set lists).
inline constexpr const char* kLidarAttributes[] = {"intensity", "classification", "return_number", "number_of_returns"};
enum LidarAttribute { kLidarIntensity, kLidarClassification, kLidarReturnNumber, kLidarNumberOfReturns, kLidarCount };
// Per-surfel opacity: after the LiDAR attributes, before the scalar ones.
inline constexpr const char* kOpacityAttribute = "opacity";
// The provenance attribute's name (docs/FORMAT.md, "Provenance"; reserved: an
// input's own field of this name is not stored beside it).
inline constexpr const char* kProvenanceAttribute = "input";
// Index in kLidarAttributes, or -1.
inline int lidarIndex(const std::string& name) {
    for (int i = 0; i < kLidarCount; ++i)
        if (name == kLidarAttributes[i]) return i;
    return -1;
}

// Decodes untrusted bytes; checks the blobs' headers and attribute set against what the tile set
// declares (expectColorBits 0 = no colour, expect* = attribute present).
// `extra` names the attributes after the fixed ones, in block order: those of
// kLidarAttributes and the opacity are decoded; any other is a scalar attribute, decoded into
// BlockData::scalars when `scalars` is set (widened to 32 bits) and skipped
// otherwise, as are a newer writer's attributes.
struct BlockExpectation {
    BlockCodec codec = BlockCodec::DracoColumns;
    int colorBits = 0;
    bool normals = true;
    bool weights = true;
    bool radii = false;
    bool edgeWeights = false;
    std::vector<std::string> extra;
    // The width of each of `extra` (scalarBits of tileset.json's type);
    // draco-columns stores a 32-bit one as two 16-bit columns, top first.
    // Empty: none wider than 16 bits.
    std::vector<int> extraBits;
    // Whether extra[e] is two columns.
    bool splitsColumn(size_t e) const { return codec == BlockCodec::DracoColumns && e < extraBits.size() && extraBits[e] == 32; }
    bool scalars = false;
    // Surfels the node's record declares: the block must hold exactly these.
    // Draco sizes its buffers by the count in the block's header before it
    // decodes anything, so the header is checked first. 0: unknown, then at
    // most kMaxBlockPoints.
    uint32_t points = 0;
};
// The most attributes one Draco point cloud of a block may declare: every
// dimension of LAS point format 10, each 32-bit one as two columns, with room
// for Extra Bytes.
inline constexpr uint32_t kMaxBlockAttributes = 128;
// The largest node surfcast-build writes (--capacity's upper bound, 2^22).
inline constexpr uint32_t kMaxBlockPoints = 4'194'304;
// What decoding one block may allocate, and so the largest block a writer
// writes: Draco holds every component as a 32-bit portable value while it
// decodes and then the point's values in their own types.
inline constexpr uint64_t kMaxBlockDecodeBytes = uint64_t(512) << 20;
inline uint64_t blockDecodeBytes(uint32_t points, uint32_t components, uint32_t valueBytes) {
    return uint64_t(points) * (4 * uint64_t(components) + valueBytes);
}
Result<BlockData> decodeBlock(const uint8_t* data, size_t size, const BlockExpectation& expect);

}  // namespace surfcast
