// LiDAR attributes end to end through the build: per-class counts and
// intensities at the leaves against values decoded from the files here, an
// extended-class LAS 1.4 round trip, and --attributes none.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <set>
#include <tuple>

#include "block_codec.h"
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
    // A name no input carries (scalar fields are named by the inputs, so it
    // is known only once they are read) is an error naming it; nothing is written.
    auto bad = test::run({test::binary("surfcast-build"), test::dataFile("Megaplot.laz"), "-o", dir.file("bad"),
                          "--attributes", "intensity,gps_tme"});
    EXPECT_EQ(bad.exitCode, 1);
    EXPECT_NE(bad.output.find("gps_tme"), std::string::npos);
    EXPECT_FALSE(std::filesystem::exists(dir.file("bad")));
}

// ---- Scalar fields: LAS 1.4 format 8 with an Extra Bytes VLR, written here ----

// A node's block with its scalar attributes decoded (readBlock skips them).
Result<BlockData> readBlockWithScalars(const TilesetReader& set, const NodeRecord& n) {
    auto bytes = set.readBlockBytes(n);
    if (!bytes) return bytes.status();
    BlockExpectation e = set.expectation(n);
    e.scalars = true;
    return decodeBlock(bytes->data(), bytes->size(), e);
}

// A scalar field's value for surfel i: its attribute's, plus its low part's
// where the field is wide (docs/FORMAT.md, "Scalar attributes"); NaN where
// the block lacks it.
double fieldValue(const TilesetInfo& info, const BlockData& b, const std::string& name, size_t i) {
    double v = NAN, low = 0;
    for (const ScalarAttribute& a : b.scalars) {
        const AttributeInfo* ai = info.attribute(a.name);
        if (a.name == name) v = a.values[i] * ai->scale + ai->offset;
        if (a.name == name + kLowPartSuffix) low = a.values[i] * ai->scale + ai->offset;
    }
    return v + low;
}

// One Extra Bytes descriptor (LAS 1.4 R15, table 24): type, options, name,
// no_data (as 8 bytes), scale and offset.
std::string extraBytesDescriptor(uint8_t type, uint8_t options, const std::string& name, uint64_t noData = 0,
                                 double scale = 1, double offset = 0) {
    std::string d(192, '\0');
    d[2] = char(type);
    d[3] = char(options);
    std::memcpy(d.data() + 4, name.data(), std::min<size_t>(name.size(), 32));
    std::memcpy(d.data() + 40, &noData, 8);
    std::memcpy(d.data() + 112, &scale, 8);
    std::memcpy(d.data() + 136, &offset, 8);
    return d;
}

// A LAS 1.4 file of `count` records of `length` bytes (filled by `fill`),
// point format `format`, with one Extra Bytes VLR holding `descriptors`.
std::string lasWithExtraBytes(int format, size_t length, uint32_t count, const std::string& descriptors,
                              const std::string& scaleAndOffset, const std::function<void(uint32_t, char*)>& fill) {
    auto put = [](std::string& s, size_t at, auto v) { std::memcpy(s.data() + at, &v, sizeof v); };
    std::string vlr(54, '\0');
    std::memcpy(vlr.data() + 2, "LASF_Spec", 9);
    put(vlr, 18, uint16_t(4));
    put(vlr, 20, uint16_t(descriptors.size()));
    vlr += descriptors;
    std::string h(375, '\0');
    std::memcpy(h.data(), "LASF", 4);
    h[24] = 1, h[25] = 4;
    put(h, 94, uint16_t(375));
    put(h, 96, uint32_t(375 + vlr.size()));
    put(h, 100, uint32_t(1));
    h[104] = char(format);
    put(h, 105, uint16_t(length));
    std::memcpy(h.data() + 131, scaleAndOffset.data(), 48);
    put(h, 247, uint64_t(count));
    std::string data(count * length, '\0');
    for (uint32_t i = 0; i < count; ++i) fill(i, data.data() + i * length);
    return h + vlr + data;
}

// Format 8 (38 bytes) then extra bytes: "amplitude" (uint16, scale 0.01,
// offset 5), "deviation" (double), 2 undocumented bytes, "spare" (uint8, no
// data 255): 51 bytes a record, from autzen's positions.
struct ScalarInput {
    std::string las;
    std::map<Key, std::map<std::string, double>> unique;  // by position, points no other shares
};

ScalarInput makeScalarLas() {
    const std::string src = test::readFile(test::dataFile("autzen_trim.las"));
    uint32_t srcOffset;
    std::memcpy(&srcOffset, src.data() + 96, 4);
    const uint32_t count = 110000;
    const std::string descriptors = extraBytesDescriptor(3, 8 | 16, "amplitude", 0, 0.01, 5) +
                                    extraBytesDescriptor(10, 0, "deviation") + extraBytesDescriptor(0, 2, "") +
                                    extraBytesDescriptor(1, 1, "spare", 255);
    std::map<Key, int> seen;
    std::map<Key, std::map<std::string, double>> values;
    ScalarInput in;
    in.las = lasWithExtraBytes(8, 51, count, descriptors, src.substr(131, 48), [&](uint32_t i, char* q) {
        const char* p = src.data() + srcOffset + i * 34;
        std::memcpy(q, p, 14);  // x, y, z, intensity
        q[14] = char(1 | 1 << 4);
        q[16] = char(uint8_t(p[15]) & 31);
        const uint8_t user = uint8_t(i % 7);
        const int16_t angle = int16_t(int(i % 1000) - 500);
        const uint16_t source = i % 2 ? 100 : 102;
        const double gps = 1000 + i * 1e-4;
        const uint16_t nir = uint16_t(i % 4096), amplitude = uint16_t(i % 5000);
        const double deviation = std::sin(double(i));
        const uint8_t spare = i % 10 == 0 ? 255 : uint8_t(i % 200);
        q[17] = char(user);
        std::memcpy(q + 18, &angle, 2);
        std::memcpy(q + 20, &source, 2);
        std::memcpy(q + 22, &gps, 8);
        for (int c = 0; c < 3; ++c) std::memcpy(q + 30 + 2 * c, p + 20 + 2 * c, 2);  // RGB
        std::memcpy(q + 36, &nir, 2);
        std::memcpy(q + 38, &amplitude, 2);
        std::memcpy(q + 40, &deviation, 8);
        q[48] = char(0xAB), q[49] = char(0xCD);  // undocumented
        q[50] = char(spare);
        int32_t xyz[3];
        std::memcpy(xyz, p, 12);
        const Key k{xyz[0], xyz[1], xyz[2]};
        seen[k]++;
        values[k] = {{"user_data", user},          {"scan_angle", angle * 0.006},
                     {"point_source_id", source},  {"gps_time", gps},
                     {"nir", nir},                 {"amplitude", amplitude * 0.01 + 5},
                     {"deviation", deviation},     {"spare", spare}};
    });
    for (auto& [k, v] : values)
        if (seen[k] == 1) in.unique[k] = v;
    return in;
}

TEST(Lidar, ScalarFieldsRoundTripThroughTheLevels) {
    REQUIRE_DATA();
    const ScalarInput input = makeScalarLas();
    ASSERT_GT(input.unique.size(), 100000u);
    TempDir dir;
    test::writeFile(dir.file("f8.las"), input.las);
    auto r = test::run({test::binary("surfcast-build"), dir.file("f8.las"), "-o", dir.file("set"), "-q", "--attributes", "all"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto set = TilesetReader::open(dir.file("set"));
    ASSERT_TRUE(set.ok()) << set.status().message();
    const TilesetInfo& info = set->info();
    // Each field with its kind; the undocumented bytes are not one.
    const std::map<std::string, std::string> kinds = {
        {"scan_angle", "continuous"}, {"user_data", "categorical"}, {"point_source_id", "categorical"},
        {"gps_time", "continuous"},   {"nir", "continuous"},        {"amplitude", "continuous"},
        {"deviation", "continuous"},  {"spare", "continuous"}};
    for (const auto& [name, kind] : kinds) {
        const AttributeInfo* a = info.attribute(name);
        ASSERT_NE(a, nullptr) << name;
        EXPECT_EQ(a->kind, kind) << name;
    }
    // gps_time (1000 + i / 10^4: doubles of 42 fraction bits over 11 s) and
    // "deviation" (sin i: doubles nearer zero than 53 bits of its range
    // reach) are wide: each a second attribute of its low bits.
    const std::vector<std::string> wide = {"gps_time", "deviation"};
    for (const std::string& name : wide) EXPECT_NE(info.attribute(name + kLowPartSuffix), nullptr) << name;
    EXPECT_EQ(info.attributes.size(), 4u /* position normal color radius */ + 4 /* LiDAR */ + kinds.size() + wide.size());

    // The largest error each may have, from its quantization: integers and
    // scaled integers exact (the files' own steps: 0.006 degree, 0.01);
    // gps_time exact (its two parts add up in a double exactly: 52 bits);
    // "deviation" (a double, no step) to half of the power of two at or above
    // its range (just under 2) over 2^53 - 1, 2^-52, plus the sum's rounding
    // (an ulp of 1); "spare" exact, its no-data value as it came (a set of
    // every attribute gives back what the file holds).
    const std::map<std::string, double> tolerance = {
        {"scan_angle", 1e-9}, {"user_data", 0}, {"point_source_id", 0}, {"gps_time", 0},
        {"nir", 0},           {"amplitude", 1e-9}, {"deviation", 0x1p-53 + 0x1p-52}, {"spare", 0}};
    std::map<std::string, size_t> checked, wrong;
    std::set<double> sources;
    for (const NodeRecord& n : set->nodes()) {
        auto block = readBlockWithScalars(*set, n);
        ASSERT_TRUE(block.ok()) << block.status().message();
        ASSERT_EQ(block->scalars.size(), kinds.size() + wide.size());
        for (const ScalarAttribute& a : block->scalars) {
            const AttributeInfo* ai = info.attribute(a.name);
            ASSERT_NE(ai, nullptr);
            if (a.name.ends_with(kLowPartSuffix)) continue;  // in its field's value
            for (size_t i = 0; i < block->size(); ++i) {
                const double v = fieldValue(info, *block, a.name, i);
                // Categorical fields are resampled by majority: only values the
                // input holds, never an average (101 between 100 and 102).
                if (a.name == "point_source_id") sources.insert(v);
                if (!(n.flags & kFlagInputPoints)) continue;
                const Vec3d p = surfelPosition(info, n, *block, i);
                Key k;
                int64_t q[3];
                for (int c = 0; c < 3; ++c) {
                    double scale, offset;
                    std::memcpy(&scale, input.las.data() + 131 + 8 * c, 8);
                    std::memcpy(&offset, input.las.data() + 155 + 8 * c, 8);
                    q[c] = std::llround((p[c] - offset) / scale);
                }
                k = Key{q[0], q[1], q[2]};
                auto it = input.unique.find(k);
                if (it == input.unique.end()) continue;
                double want = it->second.at(a.name);
                ++checked[a.name];
                if (!(std::fabs(v - want) <= tolerance.at(a.name))) {
                    if (wrong[a.name]++ < 3) ADD_FAILURE() << a.name << ": " << v << " against " << want;
                }
            }
        }
    }
    for (const auto& [name, kind] : kinds) {
        EXPECT_GT(checked[name], 100000u) << name;
        EXPECT_EQ(wrong[name], 0u) << name;
    }
    EXPECT_EQ(sources, (std::set<double>{100, 102}));
    // The undocumented extra bytes are named as left out.
    ASSERT_EQ(info.leftOut.size(), 1u);
    EXPECT_EQ(info.leftOut[0], "extra bytes 2 (undocumented)");

    // Asked for by name, a field's no-data value is no value: stored as the
    // field's minimum (0), read as its offset.
    r = test::run({test::binary("surfcast-build"), dir.file("f8.las"), "-o", dir.file("named"), "-q", "--attributes", "spare"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto named = TilesetReader::open(dir.file("named"));
    ASSERT_TRUE(named.ok()) << named.status().message();
    const AttributeInfo* spare = named->info().attribute("spare");
    ASSERT_NE(spare, nullptr);
    EXPECT_EQ(spare->offset, 1);  // i % 200 for i % 10 != 0: 1 the least
    size_t noData = 0;
    for (const NodeRecord& n : named->nodes()) {
        if (!(n.flags & kFlagInputPoints)) continue;
        auto block = readBlockWithScalars(*named, n);
        ASSERT_TRUE(block.ok()) << block.status().message();
        for (size_t i = 0; i < block->size(); ++i) noData += block->scalars[0].values[i] == 0;
    }
    EXPECT_GT(noData, 10000u);  // a tenth of the points (duplicates of position merged)
}

TEST(Lidar, ExtraBytesVlrErrorsNameTheVlr) {
    REQUIRE_DATA();
    const std::string src = test::readFile(test::dataFile("autzen_trim.las"));
    const std::string scaleAndOffset = src.substr(131, 48);
    auto fill = [](uint32_t i, char* q) {
        const int32_t xyz[3] = {int32_t(i % 100) * 100, int32_t(i / 100) * 100, 0};
        std::memcpy(q, xyz, 12);
    };
    struct Case {
        const char* name;
        std::string descriptors;
        size_t extra;  // extra bytes per record
        const char* says;
    };
    const Case cases[] = {
        {"partial", std::string(100, '\0'), 2, "192-byte descriptors"},
        {"unknown-type", extraBytesDescriptor(31, 0, "x"), 2, "unknown data type 31"},
        {"too-long", extraBytesDescriptor(10, 0, "d"), 2, "more than the 2 extra bytes"},
        {"zero-size", extraBytesDescriptor(0, 0, "z"), 2, "zero bytes"},
    };
    TempDir dir;
    for (const Case& c : cases) {
        test::writeFile(dir.file(std::string(c.name) + ".las"), lasWithExtraBytes(6, 30 + c.extra, 1000, c.descriptors, scaleAndOffset, fill));
        auto r = test::run({test::binary("surfcast-build"), dir.file(std::string(c.name) + ".las"), "-o", dir.file(c.name), "-q"});
        EXPECT_EQ(r.exitCode, 1) << c.name;
        EXPECT_NE(r.output.find("VLR 0 (Extra Bytes"), std::string::npos) << c.name << ": " << r.output;
        EXPECT_NE(r.output.find(c.says), std::string::npos) << c.name << ": " << r.output;
        EXPECT_FALSE(std::filesystem::exists(dir.file(c.name))) << c.name;
    }
}

// PLY properties that no fixed attribute takes, stored by name.
TEST(Lidar, PlyScalarPropertyStoredByName) {
    TempDir dir;
    std::string ply = "ply\nformat ascii 1.0\nelement vertex 10000\nproperty float x\nproperty float y\nproperty float z\n"
                      "property float confidence\nproperty int band\nproperty int flat\nend_header\n";
    std::map<std::pair<int, int>, std::pair<double, int>> want;
    for (int i = 0; i < 10000; ++i) {
        const int x = i % 100, y = i / 100;
        const std::string confidence = std::to_string((i % 97) / 96.0);  // 6 decimals
        ply += std::to_string(x * 0.01) + " " + std::to_string(y * 0.01) + " 0 " + confidence + " " + std::to_string(i % 5) + " 7\n";
        want[{x, y}] = {std::stod(confidence), i % 5};  // as the reader parses the text
    }
    test::writeFile(dir.file("c.ply"), ply);
    auto r = test::run({test::binary("surfcast-build"), dir.file("c.ply"), "-o", dir.file("set"), "-q", "--attributes",
                        "confidence,band,flat"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    // A constant property carries nothing per point: its value is recorded once, in no block.
    auto set = TilesetReader::open(dir.file("set"));
    ASSERT_TRUE(set.ok());
    ASSERT_NE(set->info().constant("flat"), nullptr);
    EXPECT_EQ(set->info().constant("flat")->value, 7);
    const AttributeInfo* confidence = set->info().attribute("confidence");
    const AttributeInfo* band = set->info().attribute("band");
    ASSERT_TRUE(confidence && band);
    EXPECT_EQ(set->info().attribute("flat"), nullptr);
    EXPECT_EQ(band->type, "uint8");  // 0..4 at step 1
    size_t checked = 0;
    for (const NodeRecord& n : set->nodes()) {
        if (!(n.flags & kFlagInputPoints)) continue;
        auto block = readBlockWithScalars(*set, n);
        ASSERT_TRUE(block.ok()) << block.status().message();
        // confidence: the doubles of 6-decimal texts in [0, 1], finer than 53
        // bits of the range reach: wide, to half of 2^-52 (the power of two
        // at or above 1 / (2^53 - 1)) plus the sum's rounding (an ulp of 1).
        ASSERT_EQ(block->scalars.size(), 3u);
        for (size_t i = 0; i < block->size(); ++i) {
            const Vec3d p = surfelPosition(set->info(), n, *block, i);
            auto it = want.find({int(std::lround(p.x * 100)), int(std::lround(p.y * 100))});
            ASSERT_NE(it, want.end());
            EXPECT_NEAR(fieldValue(set->info(), *block, "confidence", i), it->second.first, 0x1p-53 + 0x1p-52);
            EXPECT_EQ(fieldValue(set->info(), *block, "band", i), it->second.second);
            ++checked;
        }
    }
    EXPECT_EQ(checked, 10000u);
}

}  // namespace
}  // namespace surfcast
