// LiDAR attributes end to end through the build: per-class counts and
// intensities at the leaves against values decoded from the files here, an
// extended-class LAS 1.4 round trip, and --attributes none.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <tuple>

#include "las_reader.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace surfcast {
namespace {

using test::TempDir;
using Key = std::tuple<int64_t, int64_t, int64_t>;

// One input point as the test decodes it: LAS integer coordinates, and the
// attributes. Of exact duplicates the build keeps the lowest (class,
// intensity, returns) (docs/FORMAT.md), so the test keeps the same.
struct Expected {
    int classification = 0, intensity = 0, returns = 0;
    auto tie() const { return std::tie(classification, intensity, returns); }
};

struct Decoded {
    double scale[3], offset[3];
    std::map<Key, Expected> points;  // duplicates merged
};

void keep(Decoded& d, const Key& k, const Expected& e) {
    auto [it, inserted] = d.points.insert({k, e});
    if (!inserted && e.tie() < it->second.tie()) it->second = e;
}

// An uncompressed LAS file, parsed here from the specification's tables
// (LAS 1.4 R15 tables 3, 7 and 13), not through the build's reader.
Decoded decodeLas(const std::string& bytes) {
    Decoded d;
    auto get = [&](size_t at, auto v) {
        std::memcpy(&v, bytes.data() + at, sizeof v);
        return v;
    };
    const uint32_t dataOffset = get(96, uint32_t{});
    const int format = uint8_t(bytes[104]) & 0x3F;
    const size_t length = get(105, uint16_t{});
    uint64_t count = get(107, uint32_t{});
    if (count == 0) count = get(247, uint64_t{});
    for (int a = 0; a < 3; ++a) {
        d.scale[a] = get(131 + 8 * a, double{});
        d.offset[a] = get(155 + 8 * a, double{});
    }
    for (uint64_t i = 0; i < count; ++i) {
        const size_t r = dataOffset + i * length;
        Key k{get(r, int32_t{}), get(r + 4, int32_t{}), get(r + 8, int32_t{})};
        Expected e;
        e.intensity = get(r + 12, uint16_t{});
        const uint8_t b14 = uint8_t(bytes[r + 14]);
        if (format >= 6) {
            e.returns = b14;
            e.classification = uint8_t(bytes[r + 16]);
        } else {
            e.returns = (b14 & 7) | (b14 >> 3 & 7) << 4;
            e.classification = uint8_t(bytes[r + 15]) & 31;
        }
        keep(d, k, e);
    }
    return d;
}

struct Leaves {
    std::map<int, uint64_t> classCounts;
    std::map<int, uint64_t> returnCounts;  // by the packed returns byte
    size_t intensityMismatches = 0, classMismatches = 0, unmatched = 0, surfels = 0;
};

// The leaves of a built set, each surfel matched to its input point by position.
Leaves readLeaves(const std::string& dir, const Decoded& input) {
    Leaves out;
    auto set = TilesetReader::open(dir);
    EXPECT_TRUE(set.ok()) << set.status().message();
    if (!set) return out;
    const TilesetInfo& info = set->info();
    const AttributeInfo* intensity = info.attribute("intensity");
    for (const NodeRecord& n : set->nodes()) {
        if (!(n.flags & kFlagInputPoints)) continue;
        auto block = set->readBlock(n);
        EXPECT_TRUE(block.ok()) << block.status().message();
        if (!block) continue;
        for (size_t i = 0; i < block->size(); ++i) {
            ++out.surfels;
            if (!block->classification.empty()) out.classCounts[block->classification[i]]++;
            EXPECT_EQ(block->returnNumber.empty(), block->numberOfReturns.empty());
            if (!block->returnNumber.empty() && !block->numberOfReturns.empty())
                out.returnCounts[block->returnNumber[i] | block->numberOfReturns[i] << 4]++;
            // The nearest LAS lattice point among the 8 around the decoded position.
            const Vec3d p = surfelPosition(info, n, *block, i);
            double u[3];
            for (int a = 0; a < 3; ++a) u[a] = (p[a] - input.offset[a]) / input.scale[a];
            const Expected* match = nullptr;
            double best = 1e300;
            for (int c = 0; c < 8; ++c) {
                Key k{int64_t(std::floor(u[0])) + (c & 1), int64_t(std::floor(u[1])) + (c >> 1 & 1),
                      int64_t(std::floor(u[2])) + (c >> 2 & 1)};
                auto it = input.points.find(k);
                if (it == input.points.end()) continue;
                double d = std::pow(u[0] - double(std::get<0>(k)), 2) + std::pow(u[1] - double(std::get<1>(k)), 2) +
                           std::pow(u[2] - double(std::get<2>(k)), 2);
                if (d < best) best = d, match = &it->second;
            }
            if (!match) {
                ++out.unmatched;
                continue;
            }
            if (!block->classification.empty() && block->classification[i] != match->classification) ++out.classMismatches;
            if (intensity && !block->intensity.empty() &&
                block->intensity[i] * intensity->scale + intensity->offset != double(match->intensity))
                ++out.intensityMismatches;
        }
    }
    return out;
}

std::map<int, uint64_t> classCounts(const Decoded& d) {
    std::map<int, uint64_t> counts;
    for (const auto& [k, e] : d.points) counts[e.classification]++;
    return counts;
}

TEST(Lidar, AutzenLeavesKeepEveryClassAndIntensity) {
    REQUIRE_DATA();
    const Decoded input = decodeLas(test::readFile(test::dataFile("autzen_trim.las")));
    ASSERT_GT(input.points.size(), 100000u);
    TempDir dir;
    auto r = test::run({test::binary("surfcast-build"), test::dataFile("autzen_trim.las"), "-o", dir.file("set"), "-q"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const Leaves leaves = readLeaves(dir.file("set"), input);
    EXPECT_EQ(leaves.surfels, input.points.size());
    EXPECT_EQ(leaves.unmatched, 0u);
    EXPECT_EQ(leaves.classCounts, classCounts(input));  // PROVENANCE: classes 1 and 2
    EXPECT_EQ(leaves.classCounts.size(), 2u);
    EXPECT_EQ(leaves.classMismatches, 0u);
    // Intensity 0..254 fits 12 bits: stored exactly.
    EXPECT_EQ(leaves.intensityMismatches, 0u);

    auto set = TilesetReader::open(dir.file("set"));
    ASSERT_TRUE(set.ok());
    const TilesetStatistics& st = set->info().statistics;
    EXPECT_TRUE(st.intensity);
    EXPECT_EQ(st.intensityMax, 254);
    std::vector<std::pair<int, uint64_t>> counts;  // every input point, duplicates included
    {
        std::map<int, uint64_t> all;
        const std::string bytes = test::readFile(test::dataFile("autzen_trim.las"));
        uint32_t offset;
        std::memcpy(&offset, bytes.data() + 96, 4);
        for (size_t i = 0; i < 110000; ++i) all[uint8_t(bytes[offset + i * 34 + 15]) & 31]++;
        counts.assign(all.begin(), all.end());
    }
    EXPECT_EQ(st.classCounts, counts);
}

TEST(Lidar, MegaplotClassCounts) {
    REQUIRE_DATA();
    // LAZ: decoded through the LAS reader, counted and merged here.
    auto reader = openLasReader(test::dataFile("Megaplot.laz"));
    ASSERT_TRUE(reader.ok()) << reader.status().message();
    Decoded input;
    for (int a = 0; a < 3; ++a) input.scale[a] = 0.01, input.offset[a] = 0;  // replaced below
    std::vector<InputPoint> batch(4096);
    std::vector<InputPoint> all;
    while (true) {
        auto n = (*reader)->read(batch.data(), batch.size());
        ASSERT_TRUE(n.ok());
        if (*n == 0) break;
        all.insert(all.end(), batch.begin(), batch.begin() + long(*n));
    }
    ASSERT_EQ(all.size(), 81590u);
    // Positions keyed in hundredths (Megaplot's LAS scale is 0.01).
    for (int a = 0; a < 3; ++a) input.scale[a] = 0.01;
    for (const InputPoint& p : all)
        keep(input, {std::llround(p.position.x / 0.01), std::llround(p.position.y / 0.01), std::llround(p.position.z / 0.01)},
             {p.classification, p.intensity, p.returns});
    TempDir dir;
    auto r = test::run({test::binary("surfcast-build"), test::dataFile("Megaplot.laz"), "-o", dir.file("set"), "-q"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const Leaves leaves = readLeaves(dir.file("set"), input);
    EXPECT_EQ(leaves.unmatched, 0u);
    EXPECT_EQ(leaves.classCounts, classCounts(input));
    EXPECT_EQ(leaves.classMismatches, 0u);
    EXPECT_EQ(leaves.intensityMismatches, 0u);  // 0..580: exact
    std::map<int, uint64_t> returns;
    for (const auto& [k, e] : input.points) returns[e.returns]++;
    EXPECT_EQ(leaves.returnCounts, returns);  // PROVENANCE: returns 1 to 4
    EXPECT_GE(returns.size(), 4u);
}

// LAS 1.4 point format 6 with classes past 31 (only the extended field holds
// them) and 4-bit return numbers, written here from autzen's points.
TEST(Lidar, Las14ExtendedClassesRoundTrip) {
    REQUIRE_DATA();
    const std::string src = test::readFile(test::dataFile("autzen_trim.las"));
    uint32_t srcOffset;
    std::memcpy(&srcOffset, src.data() + 96, 4);
    const uint32_t count = 110000;
    const size_t length = 30 + 4;  // format 6 and 4 extra bytes
    std::string h(375, '\0');
    std::memcpy(h.data(), "LASF", 4);
    h[24] = 1, h[25] = 4;
    auto put = [](std::string& s, size_t at, auto v) { std::memcpy(s.data() + at, &v, sizeof v); };
    put(h, 94, uint16_t(375));
    put(h, 96, uint32_t(375));
    h[104] = 6;
    put(h, 105, uint16_t(length));
    std::memcpy(h.data() + 131, src.data() + 131, 48);  // scale and offset
    put(h, 247, uint64_t(count));
    std::string data(count * length, '\0');
    for (uint32_t i = 0; i < count; ++i) {
        const char* p = src.data() + srcOffset + i * 34;
        char* q = data.data() + i * length;
        std::memcpy(q, p, 14);  // x, y, z, intensity
        const int cls = (uint8_t(p[15]) & 31) + (i % 3 == 0 ? 60 : 0);
        q[14] = char((1 + i % 9) | 9 << 4);  // return number 1-9 of 9
        q[16] = char(cls);
    }
    TempDir dir;
    test::writeFile(dir.file("f6.las"), h + data);
    const Decoded input = decodeLas(h + data);
    auto r = test::run({test::binary("surfcast-build"), dir.file("f6.las"), "-o", dir.file("set"), "-q"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const Leaves leaves = readLeaves(dir.file("set"), input);
    EXPECT_EQ(leaves.unmatched, 0u);
    EXPECT_EQ(leaves.classCounts, classCounts(input));
    EXPECT_EQ(leaves.classCounts.size(), 4u);  // 1, 2, 61, 62
    std::map<int, uint64_t> returns;
    for (const auto& [k, e] : input.points) returns[e.returns]++;
    EXPECT_EQ(leaves.returnCounts, returns);
    EXPECT_EQ(returns.size(), 9u);
}

TEST(Lidar, AttributesNoneStoresNoLidarAttribute) {
    REQUIRE_DATA();
    TempDir dir;
    for (const char* which : {"none", "default"}) {
        std::vector<std::string> args = {test::binary("surfcast-build"), test::dataFile("Megaplot.laz"), "-o",
                                         dir.file(which), "-q"};
        if (std::string(which) == "none") args.insert(args.end(), {"--attributes", "none"});
        auto r = test::run(args);
        ASSERT_EQ(r.exitCode, 0) << r.output;
    }
    auto none = TilesetReader::open(dir.file("none"));
    auto all = TilesetReader::open(dir.file("default"));
    ASSERT_TRUE(none.ok() && all.ok());
    for (const char* name : kLidarAttributes) {
        EXPECT_EQ(none->info().attribute(name), nullptr) << name;
        EXPECT_NE(all->info().attribute(name), nullptr) << name;
    }
    for (const NodeRecord& n : none->nodes()) {
        auto b = none->readBlock(n);
        ASSERT_TRUE(b.ok()) << b.status().message();
        EXPECT_TRUE(b->intensity.empty() && b->classification.empty() && b->returnNumber.empty());
    }
    EXPECT_LT(none->info().blocksBytes, all->info().blocksBytes);
    // An unknown name is a usage error naming it.
    auto bad = test::run({test::binary("surfcast-build"), test::dataFile("Megaplot.laz"), "-o", dir.file("bad"),
                          "--attributes", "intensity,gps_tme"});
    EXPECT_EQ(bad.exitCode, 2);
    EXPECT_NE(bad.output.find("gps_tme"), std::string::npos);
}

}  // namespace
}  // namespace surfcast
