// The tile-set format: tileset.json, hierarchy.bin, blocks.bin. The normative
// specification is docs/FORMAT.md; this header is its one implementation, and
// tests/tileset_format_test.cpp pins the bytes.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "block_codec.h"
#include "octree_key.h"
#include "render_defaults.h"  // generated from render_defaults.json
#include "status.h"
#include "vec3.h"

namespace surfcast {

// Version 2 adds the LiDAR attributes (intensity, classification, returns) and
// `statistics`; a version-1 reader would reject their blocks' extra attributes.
// hierarchy.bin's readers take versions 1 and 2, tileset.json's 1 to 3.
inline constexpr int kFormatVersion = 2;
inline constexpr int kOldestFormatVersion = 1;
// tileset.json of a set whose blocks lie in several files (blocks.parts):
// written only by such sets, so that readers of version 2 refuse them whole.
inline constexpr int kPartsFormatVersion = 3;
// The most files a set's blocks may lie in (a bound on what tileset.json may ask a reader to open).
inline constexpr size_t kMaxBlocksParts = 65536;

// A file of the set's blocks: the blocks' byte space is the concatenation of
// the parts in order, and a node's block offset is into that space (docs/FORMAT.md, "blocks.bin").
struct BlocksPart {
    std::string file;  // "blocks.bin" or "blocks-XXXXXXXX.bin" (the part's CRC-32)
    uint64_t bytes = 0;
    bool operator==(const BlocksPart&) const = default;
};
inline constexpr char kHierarchyMagic[4] = {'S', 'C', 'H', 'Y'};
inline constexpr uint32_t kHierarchyHeaderSize = 32;
inline constexpr uint32_t kPageEntrySize = 16;
inline constexpr uint32_t kRecordSize = 64;
inline constexpr uint32_t kNoPage = 0xFFFFFFFFu;
// Levels per hierarchy page: a client fetches a page (at most 1+8+..+8^4 = 4681
// records, 300 KB) per request instead of the whole hierarchy of a huge set.
inline constexpr uint32_t kDefaultPageDepth = 5;
// Default k of the reconstruction kernel V^r = (k h)^2 I, h the node spacing
// (P95 of the 8th-neighbour distance, about 1.5-2 sampling steps). Measured
// by bench/accuracy_bench.py: mean FLIP against exact references falls from
// 0.34 at k = 1 to 0.21 at k = 0.5. Single-pixel pinholes in the scanned
// default scene (demo view): 10 of 116 K covered pixels at 0.5, 135 at 0.4,
// 3 at 0.6, none at 0.7.
inline constexpr double kDefaultKernelScale = defaults::kKernelScale;  // render_defaults.json
// Default visibility offset z_t as a multiple of a splat's footprint (k h when
// magnified): fragments within it of the nearest surface blend. The analytic
// weights count only neighbours that blend, i.e. within it along the normal.
inline constexpr double kDefaultZt = defaults::kZt;  // render_defaults.json

enum NodeFlags : uint16_t {
    kFlagConeFull = 1u << 0,       // normals span more than a hemisphere: never backface-cull
    kFlagHasRadius = 1u << 1,      // block carries a per-surfel radius attribute
    kFlagChildrenInPage = 1u << 2, // children live in page `child_page`, not in this page
    kFlagInputPoints = 1u << 3,    // leaf: the surfels are the input points themselves
    kFlagEdgeWeights = 1u << 4,    // block carries per-surfel edge-weight ratios (captured weights)
};

// Most quantization bits per position axis a record may declare: what
// surfcast-build writes at most (a node's edge in 2^30 steps is finer than
// the float positions renderers draw).
inline constexpr int kMaxPositionBits = 30;

// One node of the octree as stored in hierarchy.bin (64 bytes, little-endian).
struct NodeRecord {
    NodeKey key;
    uint8_t childMask = 0;       // bit i: child i exists (see NodeKey::child)
    uint16_t flags = 0;          // NodeFlags
    uint64_t blockOffset = 0;    // byte offset of the node's Draco blob in blocks.bin
    uint32_t blockSize = 0;      // bytes
    uint32_t blockCrc = 0;       // CRC-32 of the blob
    uint32_t surfelCount = 0;
    float spacing = 0;           // h, world units
    Vec3f coneAxis{0, 0, 1};     // unit vector, world space
    float coneCosHalfAngle = -1; // cos of the cone's half-angle; -1 with kFlagConeFull
    uint8_t positionBits = 0;    // quantization bits per axis of the block's positions, 1 to kMaxPositionBits
    uint32_t childPage = kNoPage;

    bool operator==(const NodeRecord&) const = default;
};

void encodeRecord(const NodeRecord& record, uint8_t out[kRecordSize]);
NodeRecord decodeRecord(const uint8_t in[kRecordSize]);

// hierarchy.bin from the set's nodes (any order; must form one tree rooted at
// level 0). Pages are subtrees of pageDepth levels in breadth-first order.
std::vector<uint8_t> writeHierarchy(std::vector<NodeRecord> nodes, uint32_t pageDepth = kDefaultPageDepth);
// The nodes' keys in the order hierarchy.bin stores their records: the order in
// which the writer lays out blocks.bin, so siblings sit together.
std::vector<NodeKey> hierarchyOrder(const std::vector<NodeRecord>& nodes, uint32_t pageDepth = kDefaultPageDepth);

// hierarchy.bin in the units a reader receives (docs/FORMAT.md): the header
// and page table first, then pages, each validated on its own as it arrives,
// so a reader that fetches pages lazily checks exactly what it fetched. Every
// reader of a set (local, server, streaming) goes through these two.
struct HierarchyPageEntry {
    uint64_t offset = 0;   // byte offset of the page in hierarchy.bin
    uint32_t records = 0;  // records in the page
    uint32_t crc = 0;      // CRC-32 of the page's records
};
struct HierarchyIndex {
    uint32_t pageDepth = 0;
    uint32_t nodeCount = 0;  // nodes in the whole hierarchy
    std::vector<HierarchyPageEntry> pages;
};
// The header and page table, from the first 32 + 16·P bytes of a
// hierarchy.bin of fileBytes bytes (`bytes` may hold more): magic, version,
// record size, the table's CRC, and every page inside the file. `what` names
// the file in errors.
Result<HierarchyIndex> readHierarchyIndex(std::span<const uint8_t> bytes, uint64_t fileBytes, const std::string& what);
// Page `page` of the index (`bytes`: exactly its records): its CRC, its first
// record's key `root` (the key of the record that points to the page; the
// root key for page 0), records in breadth-first order with every child
// present, child pages after this one, levels up to kMaxLevel, and every
// node's block inside blocks.bin's blocksBytes with at most kMaxBlockPoints
// surfels, 1 to kMaxPositionBits position bits and a finite spacing > 0. Returns the page's records, leaving out a later page's first
// record, which repeats its proxy in an earlier page.
Result<std::vector<NodeRecord>> readHierarchyPage(const HierarchyIndex& index, uint32_t page, std::span<const uint8_t> bytes,
                                                  const NodeKey& root, uint64_t blocksBytes, const std::string& what);
// The whole hierarchy.bin through the two above, plus what only the whole
// file shows: every page but page 0 referenced by exactly one proxy, and the
// node count. Nodes come back once each, page by page, each page breadth first.
Result<std::vector<NodeRecord>> readHierarchy(const std::vector<uint8_t>& bytes, const std::string& what);

struct AttributeInfo {
    std::string name;       // position, normal, color, weight, radius, edge_weight, a LiDAR attribute, opacity or a scalar
    std::string type;       // uint8, uint16, uint32, float32
    int components = 0;
    int quantizationBits = 0;  // Draco quantization of float attributes; 0 for integers
    // LiDAR, opacity and scalar attributes only (empty kind for the fixed ones):
    // categorical or continuous, and the value = stored · scale + offset.
    std::string kind{};  // ({}: brace lists may end before it, no -Wmissing-field-initializers)
    double scale = 1, offset = 0;
    bool operator==(const AttributeInfo&) const = default;
};

// Per-set statistics of the input points, for a viewer to choose colour ranges
// and list classes without reading blocks (docs/FORMAT.md).
struct TilesetStatistics {
    double elevationMin = 0, elevationMax = 0;      // z of the input points
    bool intensity = false;                          // the set stores intensity
    double intensityMin = 0, intensityMax = 0, intensityP2 = 0, intensityP98 = 0;
    std::vector<std::pair<int, uint64_t>> classCounts;  // (class, input points), classes with points, ascending
    bool operator==(const TilesetStatistics&) const = default;
};

// The name suffix of a wide scalar field's low part: a field exact in more
// than 32 bits is two attributes, NAME and NAME:low, whose values add up to
// its value (docs/FORMAT.md, "Scalar attributes").
inline constexpr const char* kLowPartSuffix = ":low";

// A dimension every input point carries with one value: recorded once in
// tileset.json instead of per surfel, and given back by every export.
struct ConstantAttribute {
    std::string name;  // a LiDAR attribute's or a scalar field's name
    double value = 0;
    bool operator==(const ConstantAttribute&) const = default;
};

// What the LAS/LAZ inputs' headers say beyond their points, where every such
// input agrees, so that a LAS export gives it back (docs/FORMAT.md, "las").
struct LasSourceInfo {
    bool present = false;        // some input was LAS or LAZ
    int pointFormat = -1;        // the inputs' point data record format (0-10); -1 where they differ
    int gpsTimeType = -1;        // global encoding bit 0: 0 GPS week time, 1 adjusted standard GPS time; -1 unknown
    // Empty where they differ; a LAS export writes the system identifier back
    // and names itself the generating software (the inputs' is kept for reference).
    std::string systemIdentifier, generatingSoftware;
    int creationDay = -1, creationYear = -1;            // -1 where they differ
    Vec3d scale, offset;         // the coordinate lattice (scale 0 where they differ)
    // How the inputs wrote a set's 8-bit colour c in LAS's 16-bit fields: c
    // itself (1), c·256 or c·257 (LAS's convention, and where they differ).
    int colorMultiplier = 257;
    // The coordinate system's VLRs (user LASF_Projection) as the inputs have
    // them: record id and payload (WKT 2112, GeoTIFF 34735-34737).
    std::vector<std::pair<uint16_t, std::vector<uint8_t>>> crsVlrs;
    // The Extra Bytes VLR's 192-byte descriptors of the dimensions the set
    // knows by name (FORMAT.md "Scalar attributes"), in record order.
    std::vector<std::vector<uint8_t>> extraBytes;
    bool operator==(const LasSourceInfo&) const = default;
};

// Everything in tileset.json.
struct TilesetInfo {
    std::string generator;
    uint64_t inputPoints = 0;  // points accepted from the inputs
    uint64_t surfels = 0;      // surfels stored over all nodes
    uint64_t nodes = 0;
    int levels = 0;            // deepest level + 1
    int grid = 128;            // G: cells per axis of a node's sampling grid
    Vec3d rootMin;             // double-precision origin of the octree (world units)
    double rootEdge = 0;       // edge length of the cubic root box
    Box3d bounds;              // tight bounds of the input points
    int colorBits = 0;         // 0: no colour; 8 or 16 bits per channel
    std::vector<AttributeInfo> attributes;  // in the order they appear in each block
    std::vector<ConstantAttribute> constants;  // dimensions of one value over the set, in no block
    // Dimensions some input carries that the set neither stores nor holds as
    // a constant (a viewing set: not an archive of its inputs).
    std::vector<std::string> leftOut;
    LasSourceInfo las;
    // Leaves hold every input point (a set built with --attributes all: an
    // archive of its inputs), not one of each exact duplicate position.
    bool duplicatesKept = false;
    // A preview (surfcast-build --preview): built from every previewStride-th
    // input point while the set itself is built; 0: a set. A refinement of
    // it (refine.h) holds a share previewDone of the input points at full
    // detail, in [0, 1); 0 in the first preview.
    uint32_t previewStride = 0;
    double previewDone = 0;
    TilesetStatistics statistics;
    std::string normalSource;  // input | estimated-scan-origin | estimated-up | estimated-outward
    std::string weights;       // analytic | captured | none
    std::string textureFilter;  // optimal | ewa | nearest where the set was built from textured meshes; empty otherwise
    // The inputs' names, by provenance value (the "input" attribute), where
    // the set holds more than one input; empty otherwise.
    std::vector<std::string> inputs;
    double kernelScale = 1.0;  // k of the reconstruction kernel V^r = (k h)^2 I the weights assume
    // The hierarchy's file: "hierarchy.bin", or "hierarchy-XXXXXXXX.bin" (its
    // CRC in hex) in a set updated in place, so that readers holding the
    // previous tileset.json still find the previous hierarchy (kHierarchyFile*).
    std::string hierarchyFile = "hierarchy.bin";
    uint64_t hierarchyBytes = 0;
    uint32_t hierarchyPages = 0;
    uint32_t hierarchyCrc = 0;  // CRC-32 of the whole hierarchy.bin
    uint64_t blocksBytes = 0;
    BlockCodec blockCodec = BlockCodec::DracoColumns;  // how every block is coded (blocks.codec)
    // The files the blocks lie in, where more than blocks.bin (an update in
    // place adds one a version); empty: blocks.bin alone, of blocksBytes.
    std::vector<BlocksPart> blocksParts;
    uint32_t pageDepth = kDefaultPageDepth;
    int version = kFormatVersion;  // as read; writers write kFormatVersion, or kPartsFormatVersion with blocksParts

    bool operator==(const TilesetInfo&) const = default;
    const AttributeInfo* attribute(const std::string& name) const {
        for (const AttributeInfo& a : attributes)
            if (a.name == name) return &a;
        return nullptr;
    }
    // Draco's quantization bits of the normals (the `normal` attribute's), or `fallback` where none are given.
    int normalBits(int fallback) const {
        const AttributeInfo* normal = attribute("normal");
        return normal && normal->quantizationBits > 0 ? normal->quantizationBits : fallback;
    }
    const ConstantAttribute* constant(const std::string& name) const {
        for (const ConstantAttribute& c : constants)
            if (c.name == name) return &c;
        return nullptr;
    }
};

// Whether a set's normals point out of its surfaces, from tileset.json's
// normal_source: normals read from the inputs (meshes, oriented scans) or
// turned towards the scanner that saw each point. Not those turned up or away
// from the centre, which hold for ground and closed objects only: splats
// are drawn two-sided and nodes are not culled by their cones there.
bool normalsOriented(const std::string& normalSource);

// The hierarchy file name of an updated set whose hierarchy has CRC `crc`;
// and whether `name` is a hierarchy file name a reader may open (never a
// path: tileset.json is untrusted).
std::string versionedHierarchyFile(uint32_t crc);
bool validHierarchyFile(const std::string& name);
// The same for the files of the blocks: "blocks-XXXXXXXX.bin", and blocks.bin.
std::string versionedBlocksFile(uint32_t crc);
bool validBlocksFile(const std::string& name);
// The set's block files in order: info.blocksParts, or blocks.bin alone.
std::vector<BlocksPart> blocksPartsOf(const TilesetInfo& info);

// Where bytes of the blocks' space lie: part `part`, from `offset` in its file.
struct BlockPlace {
    size_t part = 0;
    std::string file;
    uint64_t offset = 0;
};
// The blocks' space over its files (docs/FORMAT.md, "blocks.bin"), the one
// place every reader finds a node's block: the server, the tile sources,
// compaction and updates.
class BlocksLayout {
public:
    BlocksLayout() = default;  // no files: every place fails
    explicit BlocksLayout(std::vector<BlocksPart> parts);
    const std::vector<BlocksPart>& parts() const { return parts_; }
    // The file holding bytes [offset, offset + size), which must start
    // before the space's end and lie inside one file; else an error. A
    // binary search: tileset.json may list 65,536 files.
    Result<BlockPlace> place(uint64_t offset, uint64_t size) const;

private:
    std::vector<BlocksPart> parts_;
    std::vector<uint64_t> ends_;  // running sums of the parts' bytes
};
// The build record beside a hierarchy file (docs/FORMAT.md, "Updates in
// place"): build.bin beside hierarchy.bin, build-XXXXXXXX.bin beside
// hierarchy-XXXXXXXX.bin. Readers of the set never read it.
std::string buildRecordFile(const std::string& hierarchyFile);
// The files one version of a set names besides tileset.json: its hierarchy,
// the build record beside it, and its block files.
std::vector<std::string> versionFiles(const TilesetInfo& info);
// Whether `name` is one some version of a set may name (a hierarchy, build
// record or block file's): what an update may delete once no kept version
// names it, where nothing else of a set's folder or prefix is ever deleted.
bool versionFileName(const std::string& name);

std::string writeTilesetJson(const TilesetInfo& info);
Result<TilesetInfo> readTilesetJson(const std::string& text, const std::string& what);
// hierarchy.bin as the set's tileset.json describes it: its size and CRC, then
// readHierarchy's checks with every node's block inside blocks.bin's declared
// size. What every reader that takes the whole file at once (local, server,
// streaming) runs, so none trusts a block range the others would reject.
// `what` names the file.
Result<std::vector<NodeRecord>> readHierarchyOf(const TilesetInfo& info, const std::vector<uint8_t>& bytes,
                                                const std::string& what);

// Edge length of a node at `level`, and its box minimum, in world units.
double nodeEdge(const TilesetInfo& info, int level);
Vec3d nodeMin(const TilesetInfo& info, const NodeKey& key);

}  // namespace surfcast
