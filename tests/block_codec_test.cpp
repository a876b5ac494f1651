#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>
#include <map>
#include <set>
#include <tuple>

#include "block_codec.h"
#include "test_support.h"

#include <nlohmann/json.hpp>

using namespace surfcast;

namespace {
BlockData sampleBlock(size_t n) {
    BlockData b;
    for (size_t i = 0; i < n; ++i) {
        b.positions.insert(b.positions.end(), {uint32_t(i * 7 % 1024), uint32_t(i * 13 % 1024), uint32_t(i % 1024)});
        b.normals.insert(b.normals.end(), {0.f, 0.6f, 0.8f});
        b.colors.insert(b.colors.end(), {uint16_t(i % 256), uint16_t(255 - i % 256), 7});
        b.weights.push_back(0.1f + 0.001f * float(i % 100));
    }
    return b;
}

using PositionKey = std::tuple<uint32_t, uint32_t, uint32_t>;
PositionKey positionOf(const BlockData& b, size_t i) { return {b.positions[3 * i], b.positions[3 * i + 1], b.positions[3 * i + 2]}; }
}  // namespace

// The kd-tree coder reorders points: check the per-point tuples survive as sets.
TEST(BlockCodec, RoundTripKeepsEveryPointsAttributesTogether) {
    BlockData in = sampleBlock(500);
    BlockCodecOptions opt;
    opt.positionBits = 10;
    auto bytes = encodeBlock(in, opt);
    ASSERT_TRUE(bytes.ok()) << bytes.status().message();
    BlockExpectation e;
    e.colorBits = 8;
    auto out = decodeBlock(bytes->data(), bytes->size(), e);
    ASSERT_TRUE(out.ok()) << out.status().message();
    ASSERT_EQ(out->size(), in.size());
    std::map<PositionKey, std::pair<uint16_t, float>> expected;
    for (size_t i = 0; i < in.size(); ++i) expected[positionOf(in, i)] = {in.colors[3 * i], in.weights[i]};
    for (size_t i = 0; i < out->size(); ++i) {
        auto it = expected.find(positionOf(*out, i));
        ASSERT_NE(it, expected.end());
        EXPECT_EQ(out->colors[3 * i], it->second.first);
        // 12-bit quantization over the block's weight range [0.1, 0.199].
        EXPECT_NEAR(out->weights[i], it->second.second, 0.1 / 4095 + 1e-6);
        // 8-bit octahedral normals: at most 0.952° off (1.66e-2 rad; 10^6
        // random normals, bench/BENCHMARKS.md "Block coding"), so no
        // component moves by more.
        EXPECT_NEAR(out->normals[3 * i + 1], 0.6f, 1.7e-2);
    }
}

TEST(BlockCodec, RejectsTruncatedAndMismatchedBlocks) {
    auto bytes = encodeBlock(sampleBlock(300), BlockCodecOptions{});
    ASSERT_TRUE(bytes.ok());
    BlockExpectation e;
    e.colorBits = 8;
    for (size_t cut : {size_t(0), size_t(5), bytes->size() / 2, bytes->size() - 1})
        EXPECT_FALSE(decodeBlock(bytes->data(), cut, e).ok()) << "cut at " << cut;
    BlockExpectation wrong = e;
    wrong.radii = true;
    EXPECT_FALSE(decodeBlock(bytes->data(), bytes->size(), wrong).ok());
    wrong = e;
    wrong.colorBits = 16;
    EXPECT_FALSE(decodeBlock(bytes->data(), bytes->size(), wrong).ok());
}

// Draco sized its buffers by the point count in a block's header before
// decoding anything: a block claiming 2^31 - 1 points made it allocate
// gigabytes (fuzz_block). The count is checked against the node's record
// (or, unknown, against the largest node a set may hold) first.
// Byte offsets below are those of the one blob of a "draco" block (a
// "draco-columns" block's blobs start with the same header; the corpus at
// the end covers them).
TEST(BlockCodec, APointCountTheRecordDoesNotDeclareIsRejectedBeforeDraco) {
    auto bytes = encodeBlock(sampleBlock(300), BlockCodecOptions{.codec = BlockCodec::Draco});
    ASSERT_TRUE(bytes.ok());
    BlockExpectation e;
    e.codec = BlockCodec::Draco;
    e.colorBits = 8;
    e.points = 300;
    ASSERT_TRUE(decodeBlock(bytes->data(), bytes->size(), e).ok());
    e.points = 299;
    auto mismatch = decodeBlock(bytes->data(), bytes->size(), e);
    ASSERT_FALSE(mismatch.ok());
    EXPECT_NE(mismatch.status().message().find("declares 300 points; the tile set declares 299"), std::string::npos)
        << mismatch.status().message();
    std::vector<uint8_t> huge = *bytes;
    const int32_t most = 0x7fffffff;
    std::memcpy(huge.data() + 11, &most, 4);  // the header's count (docs: DRACO, version, type, method, flags)
    e.points = 0;
    auto claimed = decodeBlock(huge.data(), huge.size(), e);
    ASSERT_FALSE(claimed.ok());
    EXPECT_NE(claimed.status().message().find("declares 2147483647 points"), std::string::npos) << claimed.status().message();
    // Draco's sequential decoder sized buffers by its header (3.3 GB from a
    // small block: fuzz/regressions/block); a point cloud is decoded only in
    // the method its codec names (docs/FORMAT.md: a draco block kd-tree).
    std::vector<uint8_t> sequential = *bytes;
    sequential[8] = 0;
    auto method = decodeBlock(sequential.data(), sequential.size(), e);
    ASSERT_FALSE(method.ok());
    EXPECT_NE(method.status().message().find("not kd-tree coded"), std::string::npos) << method.status().message();
    // Bytes 5 and 6: the bitstream's major and minor version. The fields read
    // above are where Draco 2.x puts them; any other major is refused before
    // they are trusted (it once was not looked at).
    ASSERT_EQ((*bytes)[5], 2) << "Draco 1.5 writes bitstream 2.x";
    for (uint8_t major : {uint8_t(0), uint8_t(1), uint8_t(3), uint8_t(255)}) {
        std::vector<uint8_t> other = *bytes;
        other[5] = major;
        auto version = decodeBlock(other.data(), other.size(), e);
        ASSERT_FALSE(version.ok()) << int(major);
        EXPECT_NE(version.status().message().find("the block is bitstream version " + std::to_string(major) + "." +
                                                  std::to_string((*bytes)[6]) + "; readers take 2.x"),
                  std::string::npos)
            << version.status().message();
    }
    // Draco sized each attribute by the descriptors that follow (2 GB from a
    // small block); their count must be the set's, and each has 1 to 4
    // components. Byte 16: the attribute count; 17-20 the first descriptor.
    ASSERT_EQ((*bytes)[16], 4) << "position, normal, colour, weight";
    std::vector<uint8_t> fewer = *bytes;
    fewer[16] = 3;
    auto counted = decodeBlock(fewer.data(), fewer.size(), e);
    ASSERT_FALSE(counted.ok());
    EXPECT_NE(counted.status().message().find("block has 3 attributes; the tile set declares 4"), std::string::npos)
        << counted.status().message();
    std::vector<uint8_t> wide = *bytes;
    wide[19] = 200;
    auto components = decodeBlock(wide.data(), wide.size(), e);
    ASSERT_FALSE(components.ok());
    EXPECT_NE(components.status().message().find("has 200 components"), std::string::npos) << components.status().message();
}

// A count within the record bound times wide attributes made Draco allocate
// 3 GB from a 100-byte block (fuzz/regressions/block/kd-tree-buffer-3GB).
// Decoding holds 4 bytes per component plus the values in their own types.
// Hand-derived for the sample block, position (3 x u32), normal (3 x f32),
// colour (3 x u8), weight (1 x f32): 10 components, 31 value bytes, so
// 71 bytes a point. Widened to four 4-component f64 attributes: 16
// components, 128 value bytes, 192 bytes a point, and 2^22 points take
// 768 MiB, over the 512 MiB bound.
TEST(BlockCodec, ABlockThatWouldTakeOverHalfAGigabyteToDecodeIsRejectedBeforeDraco) {
    EXPECT_EQ(blockDecodeBytes(1000, 10, 31), 71'000u);
    auto bytes = encodeBlock(sampleBlock(300), BlockCodecOptions{.codec = BlockCodec::Draco});
    ASSERT_TRUE(bytes.ok());
    BlockExpectation e;
    e.codec = BlockCodec::Draco;
    e.colorBits = 8;
    // Descriptors from byte 17, five bytes each: type, data type, components,
    // normalized, a one-byte id.
    std::vector<uint8_t> wide = *bytes;
    for (size_t at = 17; at < 17 + 4 * 5; at += 5) {
        wide[at + 1] = 10;  // DT_FLOAT64
        wide[at + 2] = 4;
    }
    const int32_t count = int32_t(kMaxBlockPoints);
    std::memcpy(wide.data() + 11, &count, 4);
    auto claimed = decodeBlock(wide.data(), wide.size(), e);
    ASSERT_FALSE(claimed.ok());
    EXPECT_NE(claimed.status().message().find("4194304 points of 16 components would take 768 MiB to decode"),
              std::string::npos)
        << claimed.status().message();
}

// draco-columns: the other attributes follow the positions' decoded order
// in their own blob. Points at one position with different values (a set
// with --attributes all keeps them) keep their values together, a 32-bit
// scalar over its whole range (two 16-bit columns; Draco's sequential coder
// takes values below 2^31 only) comes back exact, and the footprint bound
// counts both blobs.
TEST(BlockCodec, ColumnsFollowThePositionsDecodedOrder) {
    BlockData in = sampleBlock(600);
    ScalarAttribute wide{"gps_time", 32, {}}, narrow{"user_data", 8, {}};
    for (size_t i = 0; i < in.size(); ++i) {
        if (i % 4 == 1) std::copy_n(in.positions.begin() + 3 * (i - 1), 3, in.positions.begin() + 3 * i);  // a copy's position
        in.intensity.push_back(uint16_t(i * 101 % 65536));
        wide.values.push_back(uint32_t(i * 2654435761u));  // spans [0, 2^32)
        narrow.values.push_back(uint8_t(i * 7));
    }
    in.scalars = {wide, narrow};
    auto bytes = encodeBlock(in, BlockCodecOptions{.positionBits = 10});
    ASSERT_TRUE(bytes.ok()) << bytes.status().message();
    BlockExpectation e;
    e.colorBits = 8;
    e.extra = {"intensity", "gps_time", "user_data"};
    e.extraBits = {16, 32, 8};
    e.scalars = true;
    e.points = uint32_t(in.size());
    auto out = decodeBlock(bytes->data(), bytes->size(), e);
    ASSERT_TRUE(out.ok()) << out.status().message();
    ASSERT_EQ(out->size(), in.size());
    ASSERT_EQ(out->scalars.size(), 2u);
    using Point = std::tuple<PositionKey, uint16_t, uint16_t, uint32_t, uint32_t>;
    auto points = [](const BlockData& b) {
        std::multiset<Point> all;
        for (size_t i = 0; i < b.size(); ++i)
            all.insert({positionOf(b, i), b.colors[3 * i], b.intensity[i], b.scalars[0].values[i], b.scalars[1].values[i]});
        return all;
    };
    EXPECT_EQ(points(*out), points(in));
    // Without the widths the columns do not add up to the attributes listed.
    e.extraBits = {};
    EXPECT_FALSE(decodeBlock(bytes->data(), bytes->size(), e).ok());
    e.extraBits = {16, 32, 8};
    // u32 length, the positions blob, then the columns blob. Its descriptors
    // widened (six attributes in seven columns: normal, colour, weight,
    // intensity, two gps_time halves, user data) and both blobs claiming 2^22 points.
    std::vector<uint8_t> claimed = *bytes;
    uint32_t kdBytes;
    std::memcpy(&kdBytes, claimed.data(), 4);
    uint8_t* columns = claimed.data() + 4 + kdBytes;
    ASSERT_EQ(columns[16], 7) << "normal, colour, weight, intensity, gps_time top and low, user data";
    for (size_t at = 17; at < 17 + 7 * 5; at += 5) {
        columns[at + 1] = 10;  // DT_FLOAT64
        columns[at + 2] = 4;
    }
    const int32_t count = int32_t(kMaxBlockPoints);
    std::memcpy(claimed.data() + 4 + 11, &count, 4);
    std::memcpy(columns + 11, &count, 4);
    e.points = 0;
    auto huge = decodeBlock(claimed.data(), claimed.size(), e);
    ASSERT_FALSE(huge.ok());
    // Positions: 3 components, 12 value bytes; the columns: 28 and 224. So 4
    // bytes for each of 31 components and 236 bytes of values: 360 bytes a
    // point, and 2^22 points take 1440 MiB.
    EXPECT_NE(huge.status().message().find("4194304 points of 31 components would take 1440 MiB to decode"), std::string::npos)
        << huge.status().message();
}

// Edge weights (4 ratios per surfel, 8-bit) travel with their point.
TEST(BlockCodec, EdgeWeightsRoundTripWithTheirPoint) {
    BlockData in = sampleBlock(400);
    for (size_t i = 0; i < in.size(); ++i)
        in.edgeWeights.insert(in.edgeWeights.end(), {1.f, 1.f + float(i % 5) * 0.5f, 0.5f, float(i % 3)});
    BlockCodecOptions opt;
    opt.positionBits = 10;
    auto bytes = encodeBlock(in, opt);
    ASSERT_TRUE(bytes.ok()) << bytes.status().message();
    BlockExpectation e;
    e.colorBits = 8;
    EXPECT_FALSE(decodeBlock(bytes->data(), bytes->size(), e).ok()) << "an undeclared attribute must be rejected";
    e.edgeWeights = true;
    auto out = decodeBlock(bytes->data(), bytes->size(), e);
    ASSERT_TRUE(out.ok()) << out.status().message();
    std::map<std::tuple<uint32_t, uint32_t, uint32_t>, size_t> index;
    for (size_t i = 0; i < in.size(); ++i) index[{in.positions[3 * i], in.positions[3 * i + 1], in.positions[3 * i + 2]}] = i;
    for (size_t i = 0; i < out->size(); ++i) {
        size_t j = index.at({out->positions[3 * i], out->positions[3 * i + 1], out->positions[3 * i + 2]});
        // 8 bits over the range [0, 3]: steps of 3/255.
        for (int k = 0; k < 4; ++k) EXPECT_NEAR(out->edgeWeights[4 * i + k], in.edgeWeights[4 * j + k], 3.0 / 255 + 1e-6);
    }
}

// LiDAR attributes travel with their points through the reordering coder; a
// reader skips an attribute whose name it does not know (a newer writer's),
// and rejects a block whose attribute count differs from what the set lists.
TEST(BlockCodec, LidarAttributesRoundTripAndUnknownOnesAreSkipped) {
    BlockData in = sampleBlock(400);
    for (size_t i = 0; i < in.size(); ++i) {
        in.intensity.push_back(uint16_t(i * 37 % 4096));
        in.classification.push_back(uint8_t(i % 3 == 0 ? 2 : 64 + i % 5));
    }
    BlockCodecOptions opt;
    opt.positionBits = 10;
    auto bytes = encodeBlock(in, opt);
    ASSERT_TRUE(bytes.ok()) << bytes.status().message();
    BlockExpectation e;
    e.colorBits = 8;
    e.extra = {"intensity", "classification"};
    auto out = decodeBlock(bytes->data(), bytes->size(), e);
    ASSERT_TRUE(out.ok()) << out.status().message();
    std::map<PositionKey, std::pair<uint16_t, uint8_t>> expected;
    for (size_t i = 0; i < in.size(); ++i) expected[positionOf(in, i)] = {in.intensity[i], in.classification[i]};
    ASSERT_EQ(out->intensity.size(), in.size());
    for (size_t i = 0; i < out->size(); ++i) {
        auto it = expected.find(positionOf(*out, i));
        ASSERT_NE(it, expected.end());
        EXPECT_EQ(out->intensity[i], it->second.first);
        EXPECT_EQ(out->classification[i], it->second.second);
    }
    e.extra = {"intensity", "wavelength"};  // the second slot under a name this reader does not know
    auto skipped = decodeBlock(bytes->data(), bytes->size(), e);
    ASSERT_TRUE(skipped.ok()) << skipped.status().message();
    EXPECT_EQ(skipped->intensity.size(), in.size());
    EXPECT_TRUE(skipped->classification.empty());
    e.extra = {"intensity"};
    EXPECT_FALSE(decodeBlock(bytes->data(), bytes->size(), e).ok());
    e.extra = {"classification", "intensity"};  // listed in the wrong order: the types disagree
    EXPECT_FALSE(decodeBlock(bytes->data(), bytes->size(), e).ok());
}

// The format's block corpus (tests/conformance/blocks.json), which
// web/test/format.test.mjs runs through the browser's decoder too: both decode
// and reject the same blocks.
TEST(FormatConformance, BlockCases) {
    const nlohmann::json corpus = test::conformanceCases("blocks.json");
    for (const auto& c : corpus["cases"]) {
        SCOPED_TRACE(c["name"].get<std::string>());
        nlohmann::json e = corpus["expect"];
        if (c.contains("expect")) e.update(c["expect"]);
        BlockExpectation expect;
        expect.codec = *parseBlockCodec(e["codec"].get<std::string>());
        expect.points = e["points"].get<uint32_t>();
        expect.colorBits = e["color_bits"].get<int>();
        expect.normals = e["normals"].get<bool>();
        expect.weights = e["weights"].get<bool>();
        expect.radii = e["radii"].get<bool>();
        expect.edgeWeights = e["edge_weights"].get<bool>();
        if (e.contains("extra")) {
            expect.extra = e["extra"].get<std::vector<std::string>>();
            expect.extraBits = e.value("extra_bits", std::vector<int>{});
            expect.scalars = true;
        }
        const std::vector<uint8_t> bytes = test::fromHex(c["block"].get<std::string>());
        auto block = decodeBlock(bytes.data(), bytes.size(), expect);
        if (c.contains("error")) {
            ASSERT_FALSE(block.ok());
            EXPECT_NE(block.status().message().find(c["error"].get<std::string>()), std::string::npos)
                << block.status().message();
        } else {
            ASSERT_TRUE(block.ok()) << block.status().message();
            EXPECT_EQ(block->positions.size(), 3 * c["count"].get<size_t>());
        }
    }
}
