// Pins docs/FORMAT.md: record bytes, hierarchy header and paging, tileset.json text,
// and runs the format's conformance corpus (tests/conformance/).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <limits>
#include <map>
#include <span>
#include <string>
#include <vector>

#include "crc32.h"
#include "test_support.h"
#include "tileset_format.h"

#include <nlohmann/json.hpp>

using namespace surfcast;

namespace {
NodeRecord sampleRecord() {
    NodeRecord r;
    r.key = {3, 1, 2, 5};
    r.childMask = 0x81;
    r.flags = kFlagConeFull | kFlagChildrenInPage;
    r.blockOffset = 0x0102030405060708ull;
    r.blockSize = 1000;
    r.blockCrc = 0xDEADBEEF;
    r.surfelCount = 20000;
    r.spacing = 0.5f;
    r.coneAxis = {0, 0, 1};
    r.coneCosHalfAngle = 0.5f;
    r.positionBits = 12;
    r.childPage = kNoPage;
    return r;
}
// A record readers accept (readHierarchyPage): position bits and spacing
// set, the rest as given.
NodeRecord valid() {
    NodeRecord r;
    r.spacing = 0.25f;
    r.positionBits = 16;
    return r;
}

// A set of `levels` levels on a root cube of edge 4 around the unit cube:
// the fields every tileset.json needs, for tests that change the rest.
TilesetInfo unitSet(int levels) {
    TilesetInfo info;
    info.rootEdge = 4;
    info.levels = levels;
    info.bounds.min = {0, 0, 0};
    info.bounds.max = {1, 1, 1};
    info.normalSource = "input";
    info.weights = "none";
    return info;
}

}  // namespace

TEST(TilesetFormat, RecordGoldenBytes) {
    // Hand-assembled from the field table in docs/FORMAT.md (little-endian).
    const uint8_t expected[kRecordSize] = {
        0x03, 0x81, 0x05, 0x00,                          // level, child mask, flags
        0x01, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00,  // x, y
        0x05, 0x00, 0x00, 0x00,                          // z
        0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01,  // block offset
        0xE8, 0x03, 0x00, 0x00, 0xEF, 0xBE, 0xAD, 0xDE,  // block size, CRC
        0x20, 0x4E, 0x00, 0x00, 0x00, 0x00, 0x00, 0x3F,  // surfels, spacing 0.5f
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,  // cone axis x, y
        0x00, 0x00, 0x80, 0x3F, 0x00, 0x00, 0x00, 0x3F,  // cone axis z, cos 0.5f
        0x0C, 0x00, 0x00, 0x00, 0xFF, 0xFF, 0xFF, 0xFF,  // position bits, reserved, child page
    };
    uint8_t bytes[kRecordSize];
    encodeRecord(sampleRecord(), bytes);
    EXPECT_EQ(0, std::memcmp(bytes, expected, kRecordSize));
    EXPECT_EQ(decodeRecord(expected), sampleRecord());
}

TEST(TilesetFormat, HierarchyHeaderAndSinglePage) {
    NodeRecord root = valid();
    root.surfelCount = 7;
    std::vector<uint8_t> bytes = writeHierarchy({root});
    ASSERT_EQ(bytes.size(), 32u + 16u + 64u);
    EXPECT_EQ(0, std::memcmp(bytes.data(), "SCHY", 4));
    auto u32 = [&](size_t at) { return uint32_t(bytes[at] | bytes[at + 1] << 8 | bytes[at + 2] << 16 | uint32_t(bytes[at + 3]) << 24); };
    EXPECT_EQ(u32(4), 2u);    // version
    EXPECT_EQ(u32(8), 64u);   // record size
    EXPECT_EQ(u32(12), 1u);   // pages
    EXPECT_EQ(u32(16), kDefaultPageDepth);
    EXPECT_EQ(u32(20), 1u);   // nodes
    EXPECT_EQ(u32(24), crc32(bytes.data() + 32, 16));
    EXPECT_EQ(u32(32), 48u);  // page 0 offset (low word)
    EXPECT_EQ(u32(40), 1u);   // page 0 records
    EXPECT_EQ(u32(44), crc32(bytes.data() + 48, 64));
}

TEST(TilesetFormat, HierarchyPagesRoundTrip) {
    // A chain 9 levels deep with a sibling at every level: with 3 levels per
    // page it needs 4 pages, whose roots repeat the proxy records.
    std::vector<NodeRecord> nodes;
    NodeKey key;
    for (int level = 0; level <= 8; ++level) {
        NodeRecord r = valid();
        r.key = key;
        r.surfelCount = uint32_t(100 + level);
        r.childMask = level < 8 ? 0x03 : 0;
        nodes.push_back(r);
        if (level < 8) {
            NodeRecord sibling = valid();
            sibling.key = key.child(1);
            sibling.surfelCount = 1;
            nodes.push_back(sibling);
        }
        key = key.child(0);
    }
    std::reverse(nodes.begin(), nodes.end());  // any input order
    std::vector<uint8_t> bytes = writeHierarchy(nodes, 3);
    auto read = readHierarchy(bytes, "test");
    ASSERT_TRUE(read.ok()) << read.status().message();
    ASSERT_EQ(read->size(), nodes.size());
    std::map<NodeKey, NodeRecord> byKey;
    for (const auto& r : *read) byKey[r.key] = r;
    for (const auto& n : nodes) {
        ASSERT_TRUE(byKey.count(n.key)) << n.key.name();
        EXPECT_EQ(byKey[n.key].surfelCount, n.surfelCount);
        EXPECT_EQ(byKey[n.key].childMask, n.childMask);
    }
    EXPECT_EQ(bytes[12], 4);  // pages
    // Proxies sit at the bottom of each page and point at a later page.
    int proxies = 0;
    for (const auto& r : *read)
        if (r.flags & kFlagChildrenInPage) {
            ++proxies;
            // Page roots at levels 0, 2, 4, 6 reach 3 levels: proxies at 2, 4, 6.
            EXPECT_EQ(r.key.level % 2, 0);
            EXPECT_GT(r.key.level, 0);
        }
    EXPECT_EQ(proxies, 3);
}

TEST(TilesetFormat, HierarchyRejectsCorruption) {
    NodeRecord root = valid();
    root.childMask = 1;
    NodeRecord child = valid();
    child.key = NodeKey{}.child(0);
    std::vector<uint8_t> bytes = writeHierarchy({root, child});
    auto flipped = bytes;
    flipped.back() ^= 0x40;
    auto r1 = readHierarchy(flipped, "h.bin");
    ASSERT_FALSE(r1.ok());
    EXPECT_NE(r1.status().message().find("page 0"), std::string::npos) << r1.status().message();
    EXPECT_NE(r1.status().message().find("CRC"), std::string::npos);
    auto truncated = bytes;
    truncated.resize(bytes.size() - 10);
    EXPECT_FALSE(readHierarchy(truncated, "h.bin").ok());
    std::vector<uint8_t> garbage(100, 0x5A);
    auto r3 = readHierarchy(garbage, "h.bin");
    ASSERT_FALSE(r3.ok());
    EXPECT_NE(r3.status().message().find("magic"), std::string::npos);
}

TEST(TilesetFormat, TilesetJsonGoldenText) {
    TilesetInfo info;
    info.generator = "surfcast-build 0.1.0";
    info.inputPoints = 1000;
    info.surfels = 1300;
    info.nodes = 9;
    info.levels = 2;
    info.grid = 128;
    info.rootMin = {-1.5, 2.25, 1000000.5};
    info.rootEdge = 4;
    info.bounds.min = {-1.5, 2.25, 1000000.5};
    info.bounds.max = {2, 3, 1000001};
    info.colorBits = 8;
    info.attributes = {{"position", "uint32", 3, 0}, {"color", "uint8", 3, 0},
                       {"intensity", "uint16", 1, 0, "continuous", 4, 100}};
    info.statistics.elevationMin = 1000000.5;
    info.statistics.elevationMax = 1000001;
    info.statistics.intensity = true;
    info.statistics.intensityMin = 100;
    info.statistics.intensityMax = 16000;
    info.statistics.intensityP2 = 180;
    info.statistics.intensityP98 = 9000;
    info.statistics.classCounts = {{1, 600}, {2, 400}};
    info.normalSource = "input";
    info.weights = "analytic";
    info.hierarchyBytes = 624;
    info.hierarchyPages = 1;
    info.hierarchyCrc = 305419896;
    info.blocksBytes = 4096;
    const char* expected = R"({
  "format": "surfcast-tileset",
  "version": 2,
  "generator": "surfcast-build 0.1.0",
  "input_points": 1000,
  "surfels": 1300,
  "nodes": 9,
  "levels": 2,
  "grid": 128,
  "root": {
    "min": [
      -1.5,
      2.25,
      1000000.5
    ],
    "edge": 4.0
  },
  "bounds": {
    "min": [
      -1.5,
      2.25,
      1000000.5
    ],
    "max": [
      2.0,
      3.0,
      1000001.0
    ]
  },
  "color_bits": 8,
  "attributes": [
    {
      "name": "position",
      "type": "uint32",
      "components": 3,
      "quantization_bits": 0
    },
    {
      "name": "color",
      "type": "uint8",
      "components": 3,
      "quantization_bits": 0
    },
    {
      "name": "intensity",
      "type": "uint16",
      "components": 1,
      "quantization_bits": 0,
      "kind": "continuous",
      "scale": 4.0,
      "offset": 100.0
    }
  ],
  "statistics": {
    "elevation": {
      "min": 1000000.5,
      "max": 1000001.0
    },
    "intensity": {
      "min": 100.0,
      "max": 16000.0,
      "p2": 180.0,
      "p98": 9000.0
    },
    "classification": {
      "counts": {
        "1": 600,
        "2": 400
      }
    }
  },
  "normal_source": "input",
  "weights": "analytic",
  "kernel_scale": 1.0,
  "hierarchy": {
    "file": "hierarchy.bin",
    "bytes": 624,
    "pages": 1,
    "page_depth": 5,
    "crc32": 305419896
  },
  "blocks": {
    "file": "blocks.bin",
    "bytes": 4096,
    "codec": "draco-columns"
  }
}
)";
    std::string text = writeTilesetJson(info);
    EXPECT_EQ(text, expected);
    auto back = readTilesetJson(text, "tileset.json");
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(*back, info);
}

// Sets coded before draco-columns say "draco"; they read back as such, and
// both readers refuse a codec they do not know (tests/conformance).
TEST(TilesetFormat, BlocksCodecRoundTrips) {
    TilesetInfo info;
    info.rootEdge = 8;
    info.levels = 1;
    info.bounds.min = {0, 0, 0};
    info.bounds.max = {1, 1, 1};
    info.normalSource = "input";
    info.weights = "none";
    info.blockCodec = BlockCodec::Draco;
    const std::string text = writeTilesetJson(info);
    EXPECT_NE(text.find("\"codec\": \"draco\"\n"), std::string::npos) << text;
    auto back = readTilesetJson(text, "tileset.json");
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(back->blockCodec, BlockCodec::Draco);
}

// A version-1 set (no statistics, no LiDAR attributes) still opens, with the
// elevation range from its bounds; an unknown future version does not.
TEST(TilesetFormat, TilesetJsonReadsVersionOne) {
    TilesetInfo info;
    info.rootEdge = 8;
    info.levels = 1;
    info.bounds.min = {0, 0, -3};
    info.bounds.max = {1, 1, 5};
    info.normalSource = "input";
    info.weights = "none";
    nlohmann::json j = nlohmann::json::parse(writeTilesetJson(info));
    j["version"] = 1;
    j.erase("statistics");
    auto back = readTilesetJson(j.dump(), "v1.json");
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(back->version, 1);
    EXPECT_EQ(back->statistics.elevationMin, -3);
    EXPECT_EQ(back->statistics.elevationMax, 5);
    EXPECT_FALSE(back->statistics.intensity);
    j["version"] = 4;
    auto future = readTilesetJson(j.dump(), "v4.json");
    ASSERT_FALSE(future.ok());
    EXPECT_NE(future.status().message().find("unsupported version 4"), std::string::npos);
}

// Version 3: blocks in several files. Written only where there are parts,
// read back as written; a node's block is found in the part that holds it
// and never across two.
TEST(TilesetFormat, BlocksInSeveralFiles) {
    TilesetInfo info;
    info.rootEdge = 8;
    info.levels = 1;
    info.normalSource = "input";
    info.weights = "none";
    info.bounds.min = {0, 0, 0};
    info.bounds.max = {1, 1, 1};
    info.blocksBytes = 300;
    EXPECT_EQ(nlohmann::json::parse(writeTilesetJson(info))["version"], kFormatVersion) << "a set of one block file stays version 2";
    info.blocksParts = {{"blocks.bin", 100}, {versionedBlocksFile(0xdeadbeef), 200}};
    const auto j = nlohmann::json::parse(writeTilesetJson(info));
    EXPECT_EQ(j["version"], kPartsFormatVersion);
    EXPECT_EQ(j["blocks"]["parts"][1]["file"], "blocks-deadbeef.bin");
    auto back = readTilesetJson(j.dump(), "v3.json");
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(back->blocksParts, info.blocksParts);
    const BlocksLayout layout(back->blocksParts);
    auto inFirst = layout.place(40, 60);
    ASSERT_TRUE(inFirst.ok());
    EXPECT_EQ(inFirst->file, "blocks.bin");
    EXPECT_EQ(inFirst->offset, 40u);
    auto inSecond = layout.place(100, 200);
    ASSERT_TRUE(inSecond.ok());
    EXPECT_EQ(inSecond->file, "blocks-deadbeef.bin");
    EXPECT_EQ(inSecond->offset, 0u);
    EXPECT_EQ(inSecond->part, 1u);
    EXPECT_EQ(layout.place(299, 1)->offset, 199u);
    EXPECT_FALSE(layout.place(90, 20).ok()) << "a block across two files";
    EXPECT_FALSE(layout.place(300, 1).ok()) << "a block past the end";
    EXPECT_TRUE(validBlocksFile("blocks.bin") && validBlocksFile("blocks-0123abcd.bin"));
    EXPECT_FALSE(validBlocksFile("blocks-0123ABCD.bin") || validBlocksFile("../blocks.bin") || validBlocksFile("blocks-123.bin"));
}

TEST(TilesetFormat, TilesetJsonRejectsBadInput) {
    EXPECT_FALSE(readTilesetJson("{", "t.json").ok());
    EXPECT_FALSE(readTilesetJson("{\"format\": \"surfcast-tileset\", \"version\": 1}", "t.json").ok());
    auto r = readTilesetJson("{\"format\": \"other\"}", "t.json");
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("t.json"), std::string::npos);
}

// Fields that size shifts and Draco options are range-checked, with the field
// named: color_bits feeds 1 << bits in the renderer.
TEST(TilesetFormat, TilesetJsonRejectsOutOfRangeBits) {
    TilesetInfo info = unitSet(2);
    info.colorBits = 8;
    info.attributes = {{"position", "uint32", 3, 0}, {"normal", "float32", 3, 8}};
    const std::string good = writeTilesetJson(info);
    auto base = readTilesetJson(good, "t.json");
    ASSERT_TRUE(base.ok()) << base.status().message();
    auto with = [&](const std::string& from, const std::string& to) {
        std::string text = good;
        const size_t at = text.find(from);
        EXPECT_NE(at, std::string::npos) << from;
        return text.replace(at, from.size(), to);
    };
    for (const char* bits : {"40", "7", "-8", "32"}) {
        auto r = readTilesetJson(with("\"color_bits\": 8", std::string("\"color_bits\": ") + bits), "t.json");
        ASSERT_FALSE(r.ok()) << bits;
        EXPECT_NE(r.status().message().find("color_bits"), std::string::npos) << r.status().message();
        EXPECT_NE(r.status().message().find("t.json"), std::string::npos) << r.status().message();
    }
    EXPECT_TRUE(readTilesetJson(with("\"color_bits\": 8", "\"color_bits\": 16"), "t.json").ok());
    EXPECT_TRUE(readTilesetJson(with("\"color_bits\": 8", "\"color_bits\": 0"), "t.json").ok());
    auto r = readTilesetJson(with("\"quantization_bits\": 8", "\"quantization_bits\": 99"), "t.json");
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("normal"), std::string::npos) << r.status().message();
    // Integer fields holding floats or numbers beyond their type were cast
    // unchecked (undefined behaviour for 1.1e70: fuzz_tileset,
    // fuzz/regressions/tileset). Each is an error naming the value.
    for (auto [from, to] : {std::pair{"\"version\": 2", "\"version\": 1.11111e+70"},
                            std::pair{"\"color_bits\": 8", "\"color_bits\": 8.5"},
                            std::pair{"\"levels\": 2", "\"levels\": 4294967298"},
                            std::pair{"\"quantization_bits\": 8", "\"quantization_bits\": -1e300"}}) {
        auto bad = readTilesetJson(with(from, to), "t.json");
        ASSERT_FALSE(bad.ok()) << to;
        EXPECT_NE(bad.status().message().find("t.json"), std::string::npos) << bad.status().message();
    }
    auto huge = readTilesetJson(with("\"version\": 2", "\"version\": 1.11111e+70"), "t.json");
    EXPECT_NE(huge.status().message().find("1.11111e+70"), std::string::npos) << huge.status().message();
}

// What a set keeps of its inputs beyond their points (constants, dimensions
// left out, every point, the LAS headers) round trips; each field's bad
// value is an error naming it (an Extra Bytes descriptor's type sizes the
// export's records, its scale divides).
TEST(TilesetFormat, TilesetJsonKeepsWhatTheInputsSaid) {
    TilesetInfo info = unitSet(1);
    info.constants = {{"point_source_id", 7326}, {"classification", 2}};
    info.leftOut = {"gps_time", "nir"};
    info.duplicatesKept = true;
    info.previewStride = 65;
    info.previewDone = 0.375;
    info.las.present = true;
    info.las.pointFormat = 8;
    info.las.gpsTimeType = 1;
    info.las.systemIdentifier = "LAStools";
    info.las.generatingSoftware = "las2las";
    info.las.creationDay = 59;
    info.las.creationYear = 2014;
    info.las.scale = {0.01, 0.01, 0.001};
    info.las.offset = {500000, 4000000, 0};
    info.las.colorMultiplier = 256;
    info.las.crsVlrs = {{2112, {'G', 'E', 'O', 'G', 'C', 'S', 0}}};
    std::vector<uint8_t> descriptor(192, 0);
    descriptor[2] = 9;  // float32
    std::memcpy(&descriptor[4], "amplitude", 9);
    info.las.extraBytes = {descriptor};
    const std::string text = writeTilesetJson(info);
    auto back = readTilesetJson(text, "t.json");
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(*back, info);
    EXPECT_NE(text.find("\"data\": \"47454f47435300\""), std::string::npos) << text;  // the payload in hex

    const nlohmann::json good = nlohmann::json::parse(text);
    auto rejected = [&](const std::string& pointer, const nlohmann::json& value, const std::string& named) {
        nlohmann::json j = good;
        j[nlohmann::json::json_pointer(pointer)] = value;
        auto r = readTilesetJson(j.dump(), "t.json");
        ASSERT_FALSE(r.ok()) << pointer << " = " << value.dump();
        EXPECT_NE(r.status().message().find(named), std::string::npos) << r.status().message();
    };
    rejected("/constants/0/value", "seven", "constants[0].value");
    rejected("/left_out/1", 3, "left_out[1]");
    rejected("/duplicates", "some", "duplicates");
    rejected("/preview/stride", 0, "preview.stride");
    rejected("/preview/done", 1, "preview.done");
    rejected("/preview/done", -0.5, "preview.done");
    rejected("/preview", 65, "preview");
    rejected("/las/point_format", 11, "las.point_format");
    rejected("/las/gps_time_type", 2, "las.gps_time_type");
    rejected("/las/color_multiplier", 255, "las.color_multiplier");
    rejected("/las/crs_vlrs/0/data", "47454g", "las.crs_vlrs[0].data");
    rejected("/las/crs_vlrs/0/data", "474", "las.crs_vlrs[0].data");
    rejected("/las/extra_bytes/0", "00", "not a 192-byte descriptor");
    std::string bad(good["las"]["extra_bytes"][0].get<std::string>());
    bad.replace(4, 2, "0b");  // data type 11: a deprecated array
    rejected("/las/extra_bytes/0", bad, "data type 11");
    std::string unscaled(good["las"]["extra_bytes"][0].get<std::string>());
    unscaled.replace(6, 2, "08");  // scale given, and 0
    rejected("/las/extra_bytes/0", unscaled, "scale or offset");
}

// The hierarchy against tileset.json: size and CRC as declared, and every
// block inside blocks.bin's declared size (else a streaming client could ask
// for a block 4 GB past the end and retry forever).
TEST(TilesetFormat, HierarchyOfASetChecksSizesAndBlockRanges) {
    NodeRecord root = valid();
    root.childMask = 1;
    root.blockOffset = 0;
    root.blockSize = 100;
    NodeRecord child = valid();
    child.key = NodeKey{}.child(0);
    child.blockOffset = 100;
    child.blockSize = 50;
    const std::vector<uint8_t> bytes = writeHierarchy({root, child});
    TilesetInfo info;
    info.hierarchyBytes = bytes.size();
    info.hierarchyCrc = crc32(bytes.data(), bytes.size());
    info.blocksBytes = 150;
    auto good = readHierarchyOf(info, bytes, "h.bin");
    ASSERT_TRUE(good.ok()) << good.status().message();
    EXPECT_EQ(good->size(), 2u);

    info.blocksBytes = 149;  // the child's last byte is missing
    auto past = readHierarchyOf(info, bytes, "h.bin");
    ASSERT_FALSE(past.ok());
    EXPECT_NE(past.status().message().find("node 1-0-0-0 points past the end of blocks.bin"), std::string::npos)
        << past.status().message();
    EXPECT_NE(past.status().message().find("h.bin"), std::string::npos);

    // An offset near 2^64 must not wrap around the bounds check.
    child.blockOffset = ~uint64_t(0) - 10;
    const std::vector<uint8_t> wrapped = writeHierarchy({root, child});
    info.hierarchyBytes = wrapped.size();
    info.hierarchyCrc = crc32(wrapped.data(), wrapped.size());
    info.blocksBytes = 150;
    EXPECT_FALSE(readHierarchyOf(info, wrapped, "h.bin").ok());

    info.hierarchyCrc ^= 1;  // a different hierarchy than tileset.json names
    auto crc = readHierarchyOf(info, wrapped, "h.bin");
    ASSERT_FALSE(crc.ok());
    EXPECT_NE(crc.status().message().find("CRC"), std::string::npos) << crc.status().message();
}

// The units a lazy reader receives, each validated alone: the header and page
// table from their own bytes, then each page from its own bytes, with a block
// range checked in the page that holds it.
TEST(TilesetFormat, HierarchyValidatesPageByPage) {
    // The chain of HierarchyPagesRoundTrip: 4 pages of 3 levels.
    std::vector<NodeRecord> nodes;
    NodeKey key;
    for (int level = 0; level <= 8; ++level) {
        NodeRecord r = valid();
        r.key = key;
        r.childMask = level < 8 ? 0x03 : 0;
        r.blockOffset = uint64_t(level) * 10;
        r.blockSize = 10;
        nodes.push_back(r);
        if (level < 8) {
            NodeRecord sibling = valid();
            sibling.key = key.child(1);
            sibling.blockOffset = 100 + uint64_t(level) * 10;
            sibling.blockSize = 10;
            nodes.push_back(sibling);
        }
        key = key.child(0);
    }
    const std::vector<uint8_t> bytes = writeHierarchy(nodes, 3);
    const size_t tableEnd = kHierarchyHeaderSize + 4 * kPageEntrySize;

    // Only the header and page table are at hand.
    auto index = readHierarchyIndex(std::span(bytes).first(tableEnd), bytes.size(), "h.bin");
    ASSERT_TRUE(index.ok()) << index.status().message();
    ASSERT_EQ(index->pages.size(), 4u);
    EXPECT_EQ(index->pageDepth, 3u);
    EXPECT_EQ(index->nodeCount, nodes.size());
    EXPECT_EQ(index->pages[0].offset, tableEnd);
    // The table's pages must fit the file the set declares.
    auto shorter = readHierarchyIndex(std::span(bytes).first(tableEnd), bytes.size() - 1, "h.bin");
    ASSERT_FALSE(shorter.ok());
    EXPECT_NE(shorter.status().message().find("h.bin: page 3"), std::string::npos) << shorter.status().message();
    EXPECT_FALSE(readHierarchyIndex(std::span(bytes).first(tableEnd - 1), bytes.size(), "h.bin").ok());

    // Pages fetched one at a time, each root the key of the proxy met before.
    auto pageBytes = [&](uint32_t p) {
        const HierarchyPageEntry& e = index->pages[p];
        return std::span(bytes).subspan(e.offset, size_t(e.records) * kRecordSize);
    };
    std::map<NodeKey, NodeRecord> seen;
    std::vector<std::pair<uint32_t, NodeKey>> pending{{0, NodeKey{}}};
    while (!pending.empty()) {
        auto [p, root] = pending.back();
        pending.pop_back();
        auto recs = readHierarchyPage(*index, p, pageBytes(p), root, 180, "h.bin");
        ASSERT_TRUE(recs.ok()) << recs.status().message();
        for (const NodeRecord& r : *recs) {
            EXPECT_TRUE(seen.emplace(r.key, r).second) << r.key.name() << " twice";
            if (r.flags & kFlagChildrenInPage) pending.push_back({r.childPage, r.key});
        }
    }
    EXPECT_EQ(seen.size(), nodes.size());
    for (const NodeRecord& n : nodes) EXPECT_EQ(seen.count(n.key), 1u) << n.key.name();

    // Blocks end at byte 180. Page 2 holds levels 4-6, with the level-6
    // sibling's block at bytes 150-160: blocks.bin of 159 bytes fails that
    // page, naming the node, while page 1 (blocks up to byte 140) passes.
    const NodeKey root2 = NodeKey{}.child(0).child(0).child(0).child(0);
    EXPECT_TRUE(readHierarchyPage(*index, 1, pageBytes(1), NodeKey{}.child(0).child(0), 159, "h.bin").ok());
    auto past = readHierarchyPage(*index, 2, pageBytes(2), root2, 159, "h.bin");
    ASSERT_FALSE(past.ok());
    EXPECT_NE(past.status().message().find("h.bin: page 2"), std::string::npos) << past.status().message();
    EXPECT_NE(past.status().message().find("node 6-0-0-1 points past the end of blocks.bin"), std::string::npos)
        << past.status().message();
    // The wrong root (a page reached from a record that does not point to it),
    // a flipped byte and a short read each fail.
    EXPECT_FALSE(readHierarchyPage(*index, 2, pageBytes(2), NodeKey{}.child(0), 180, "h.bin").ok());
    std::vector<uint8_t> flipped(pageBytes(2).begin(), pageBytes(2).end());
    flipped[70] ^= 1;
    auto crc = readHierarchyPage(*index, 2, flipped, root2, 180, "h.bin");
    ASSERT_FALSE(crc.ok());
    EXPECT_NE(crc.status().message().find("CRC"), std::string::npos) << crc.status().message();
    EXPECT_FALSE(readHierarchyPage(*index, 2, pageBytes(2).first(64), root2, 180, "h.bin").ok());
    EXPECT_FALSE(readHierarchyPage(*index, 4, pageBytes(2), root2, 180, "h.bin").ok());
}

TEST(TilesetFormat, PagesRejectBadPositionBitsAndSpacing) {
    // Untrusted records: 0 position bits made surfelPosition divide by
    // 2^0 - 1 = 0, 64 or more shifted past a u64 (undefined); a spacing that
    // is not a positive number sizes every splat of the node. Each is refused
    // where the page is read, naming the node; 1 and kMaxPositionBits pass.
    auto readOne = [](NodeRecord r) {
        const std::vector<uint8_t> bytes = writeHierarchy({r});
        auto index = readHierarchyIndex(bytes, bytes.size(), "h.bin");
        EXPECT_TRUE(index.ok()) << index.status().message();
        const HierarchyPageEntry& e = index->pages[0];
        return readHierarchyPage(*index, 0, std::span(bytes).subspan(e.offset, size_t(e.records) * kRecordSize), NodeKey{},
                                 ~uint64_t(0), "h.bin");
    };
    for (int bits : {1, kMaxPositionBits}) {
        NodeRecord r = valid();
        r.positionBits = uint8_t(bits);
        EXPECT_TRUE(readOne(r).ok()) << bits;
    }
    for (int bits : {0, kMaxPositionBits + 1, 63, 64, 255}) {
        NodeRecord r = valid();
        r.positionBits = uint8_t(bits);
        auto read = readOne(r);
        ASSERT_FALSE(read.ok()) << bits;
        EXPECT_NE(read.status().message().find("h.bin: page 0 at byte 48: node 0-0-0-0: " + std::to_string(bits) +
                                               " position bits, not 1 to 30"),
                  std::string::npos)
            << read.status().message();
    }
    for (float spacing : {0.f, -1.f, std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
        NodeRecord r = valid();
        r.spacing = spacing;
        auto read = readOne(r);
        ASSERT_FALSE(read.ok()) << spacing;
        EXPECT_NE(read.status().message().find("node 0-0-0-0: spacing "), std::string::npos) << read.status().message();
        EXPECT_NE(read.status().message().find(" is not a positive number"), std::string::npos) << read.status().message();
    }
    // The whole-file path (local readers, the server) runs the same check.
    NodeRecord r = valid();
    r.positionBits = 64;
    auto whole = readHierarchy(writeHierarchy({r}), "h.bin");
    ASSERT_FALSE(whole.ok());
    EXPECT_NE(whole.status().message().find("64 position bits"), std::string::npos) << whole.status().message();
}

// The format's conformance corpus, which web/test/format.test.mjs runs through
// the browser's reader too: both accept and reject the same cases.
namespace {
// A case's tileset.json text: `good` with the case's changes (the corpus's "about" says which).
std::string tilesetText(const nlohmann::json& good, const nlohmann::json& c) {
    if (c.contains("text")) return c["text"].get<std::string>();
    nlohmann::json doc = good;
    const nlohmann::json set = c.value("set", nlohmann::json::object()), remove = c.value("remove", nlohmann::json::array());
    for (const auto& [pointer, value] : set.items()) doc[nlohmann::json::json_pointer(pointer)] = value;
    for (const auto& pointer : remove) {
        const nlohmann::json::json_pointer p(pointer.get<std::string>());
        nlohmann::json& parent = doc[p.parent_pointer()];
        if (parent.is_array()) parent.erase(std::stoul(p.back()));
        else parent.erase(p.back());
    }
    return doc.dump(2);
}
}  // namespace

TEST(FormatConformance, TilesetJsonCases) {
    const nlohmann::json corpus = test::conformanceCases("tileset_json.json");
    for (const auto& c : corpus["cases"]) {
        SCOPED_TRACE(c["name"].get<std::string>());
        auto info = readTilesetJson(tilesetText(corpus["good"], c), "tileset.json");
        if (c.contains("error")) {
            ASSERT_FALSE(info.ok());
            const std::string message = info.status().message();
            EXPECT_EQ(message.rfind("tileset.json: ", 0), 0u) << message;
            EXPECT_NE(message.find(c["error"].get<std::string>()), std::string::npos) << message;
            continue;
        }
        ASSERT_TRUE(info.ok()) << info.status().message();
        for (const auto& [field, want] : c["read"].items()) {
            if (field == "version") EXPECT_EQ(info->version, want.get<int>());
            else if (field == "levels") EXPECT_EQ(info->levels, want.get<int>());
            else if (field == "grid") EXPECT_EQ(info->grid, want.get<int>());
            else if (field == "color_bits") EXPECT_EQ(info->colorBits, want.get<int>());
            else if (field == "kernel_scale") EXPECT_EQ(info->kernelScale, want.get<double>());
            else if (field == "weights") EXPECT_EQ(info->weights, want.get<std::string>());
            else if (field == "blocks_bytes") EXPECT_EQ(info->blocksBytes, want.get<uint64_t>());
            else if (field == "hierarchy_file") EXPECT_EQ(info->hierarchyFile, want.get<std::string>());
            else if (field == "preview") EXPECT_EQ((std::vector<double>{double(info->previewStride), info->previewDone}), want.get<std::vector<double>>());
            else if (field == "blocks_parts") {
                std::vector<std::string> parts;
                for (const BlocksPart& part : blocksPartsOf(*info)) parts.push_back(part.file + ":" + std::to_string(part.bytes));
                EXPECT_EQ(parts, want.get<std::vector<std::string>>());
            }
            else if (field == "hierarchy_bytes") EXPECT_EQ(info->hierarchyBytes, want.get<uint64_t>());
            else if (field == "hierarchy_pages") EXPECT_EQ(info->hierarchyPages, want.get<uint32_t>());
            else if (field == "hierarchy_crc") EXPECT_EQ(info->hierarchyCrc, want.get<uint32_t>());
            else if (field == "elevation") {
                EXPECT_EQ(info->statistics.elevationMin, want[0].get<double>());
                EXPECT_EQ(info->statistics.elevationMax, want[1].get<double>());
            } else if (field == "attributes") {
                std::vector<std::string> names;
                for (const auto& a : info->attributes) names.push_back(a.name);
                EXPECT_EQ(names, want.get<std::vector<std::string>>());
            } else ADD_FAILURE() << "the corpus reads a field this test does not know: " << field;
        }
    }
}

// The hierarchy read as a streaming client reads it: the header and page
// table, then page 0 from the root, then each page its proxy record reaches.
TEST(FormatConformance, HierarchyCases) {
    const nlohmann::json corpus = test::conformanceCases("hierarchy.json");
    const uint64_t blocksBytes = corpus["blocks_bytes"].get<uint64_t>();
    for (const auto& c : corpus["cases"]) {
        SCOPED_TRACE(c["name"].get<std::string>());
        const std::vector<uint8_t> bytes = test::fromHex(c["hierarchy"].get<std::string>());
        std::vector<std::string> keys;
        Status status;
        auto index = readHierarchyIndex(bytes, bytes.size(), "h.bin");
        if (!index) status = index.status();
        std::vector<std::pair<uint32_t, NodeKey>> due;  // pages to read, with their roots
        if (index) due.push_back({0, NodeKey{}});
        for (size_t i = 0; i < due.size() && status.ok(); ++i) {
            const auto [page, root] = due[i];
            const HierarchyPageEntry& e = index->pages[page];
            auto recs = readHierarchyPage(*index, page, std::span(bytes).subspan(e.offset, size_t(e.records) * kRecordSize),
                                          root, blocksBytes, "h.bin");
            if (!recs) {
                status = recs.status();
                break;
            }
            for (const NodeRecord& r : *recs) {
                keys.push_back(r.key.name());
                if (r.flags & kFlagChildrenInPage) due.push_back({r.childPage, r.key});
            }
        }
        if (c.contains("error")) {
            ASSERT_FALSE(status.ok()) << "read " << keys.size() << " nodes";
            EXPECT_EQ(status.message().rfind("h.bin: ", 0), 0u) << status.message();
            EXPECT_NE(status.message().find(c["error"].get<std::string>()), std::string::npos) << status.message();
        } else {
            ASSERT_TRUE(status.ok()) << status.message();
            EXPECT_EQ(keys, c["nodes"].get<std::vector<std::string>>());
        }
    }
}
