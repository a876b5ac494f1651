// LAZ (through the laz crate), COPC and PCD on every shared file of those
// formats: counts, bounds and colours against PROVENANCE.md, a tile set built
// from each, truncated and corrupted copies, and the streaming LZF decoder.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>

#include "inputs.h"
#include "las_reader.h"
#include "lzf_stream.h"
#include "pcd_reader.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace fs = std::filesystem;
using namespace surfcast;

namespace {

struct Expected {
    const char* file;
    uint64_t points;     // finite points
    uint64_t skipped;    // NaN entries of organized clouds
    bool colors;
    Vec3d min, max;
};

// PROVENANCE.md (coordinates given to 6 decimals).
const Expected kFiles[] = {
    {"lone-star.laz", 518862, 0, false, {515368.602250, 4918340.364000, 2322.896250}, {515401.043000, 4918381.123750, 2338.575500}},
    {"lion_takanawa.copc.laz", 341989, 0, true, {-4.99, 1.04, -3.45}, {-0.79, 6.72, 1.12}},
    {"Megaplot.laz", 81590, 0, false, {684766.39, 5017773.08, 0.0}, {684993.29, 5018007.25, 29.97}},
    {"fragment.pcd", 113662, 0, true, {1.151989, 0.815273, 0.726409}, {3.519531, 2.761719, 1.530428}},
    {"milk_cartoon_all_small_clorox.pcd", 241407, 307200 - 241407, true, {-1.060800, -0.869233, 0.501000}, {1.152494, 0.219669, 2.063000}},
    {"table_scene_mug_stereo_textured.pcd", 209280, 307200 - 209280, true, {-0.456430, -0.510740, 0.690010}, {0.715180, 0.179230, 2.592700}},
    {"CSite1_red1-utm.pcd", 522674, 0, false, {512049.5, 5403059.5, 247.190002}, {513150.1875, 5404100.0, 426.820007}},
};

Result<std::unique_ptr<PointReader>> openAny(const std::string& path, int threads) {
    return path.ends_with(".pcd") ? openPcdReader(path) : openLasReader(path, threads);
}

struct Scan {
    uint64_t points = 0, skipped = 0;
    Box3d bounds;
    bool anyColor = false;
    std::vector<Vec3d> sample;  // every 1000th point
};

Scan scan(PointReader& r) {
    Scan s;
    std::vector<InputPoint> batch(7777);  // odd size: batches straddle chunks
    while (true) {
        auto n = r.read(batch.data(), batch.size());
        EXPECT_TRUE(n.ok()) << n.status().message();
        if (!n.ok() || *n == 0) break;
        for (size_t i = 0; i < *n; ++i) {
            s.bounds.extend(batch[i].position);
            if (batch[i].color[0] || batch[i].color[1] || batch[i].color[2]) s.anyColor = true;
            if ((s.points + i) % 1000 == 0) s.sample.push_back(batch[i].position);
        }
        s.points += *n;
    }
    s.skipped = r.skipped();
    return s;
}

std::vector<InputPoint> readPoints(PointReader& r) {
    std::vector<InputPoint> all, batch(7777);
    while (true) {
        auto n = r.read(batch.data(), batch.size());
        EXPECT_TRUE(n.ok()) << n.status().message();
        if (!n.ok() || *n == 0) break;
        all.insert(all.end(), batch.begin(), batch.begin() + long(*n));
    }
    return all;
}

bool samePoint(const InputPoint& a, const InputPoint& b) {
    return a.position == b.position && std::memcmp(a.color, b.color, sizeof a.color) == 0 && a.intensity == b.intensity &&
           a.classification == b.classification && a.returns == b.returns;
}

// A LAS 1.2 file of format 2 (RGB): `count` points, point i with colour
// channels color(i).
std::string lasWithColors(uint32_t count, uint16_t (*color)(uint32_t)) {
    constexpr size_t kHeader = 227, kRecord = 26;
    std::string f(kHeader + count * kRecord, '\0');
    auto put = [&](size_t at, auto v) { std::memcpy(f.data() + at, &v, sizeof v); };
    std::memcpy(f.data(), "LASF", 4);
    f[24] = 1;
    f[25] = 2;
    put(94, uint16_t(kHeader));
    put(96, uint32_t(kHeader));
    f[104] = 2;
    put(105, uint16_t(kRecord));
    put(107, count);
    for (int a = 0; a < 3; ++a) put(131 + 8 * a, 0.01);
    for (uint32_t i = 0; i < count; ++i) {
        const size_t r = kHeader + i * kRecord;
        put(r, int32_t(i % 1000));
        put(r + 4, int32_t(i / 1000));
        put(r + 8, int32_t(i % 7));
        for (int c = 0; c < 3; ++c) put(r + 20 + 2 * c, color(i));
    }
    return f;
}

}  // namespace

// A LAZ file of point format 1 (pointwise coding), a COPC file of format 7
// (layered, variable chunks) and Megaplot: each chunk's first record, read
// as it lies in the file with nothing decoded, is the decoder's point at
// that chunk's first record (position, colour, intensity, class, returns).
// A LAS file is read whole.
TEST(LazPcd, ChunkStartsAreTheDecodedFirstPointsOfTheChunks) {
    REQUIRE_DATA();
    const ScalarSelection every{true, {}};
    for (const char* f : {"lone-star.laz", "lion_takanawa.copc.laz", "Megaplot.laz"}) {
        SCOPED_TRACE(f);
        const std::string path = test::dataFile(f);
        auto cuts = lasCuts(path);
        ASSERT_TRUE(cuts.ok()) << cuts.status().message();
        auto whole = openLasReader(path, 2, every);
        ASSERT_TRUE(whole.ok());
        const std::vector<InputPoint> all = readPoints(**whole);
        auto starts = openLasChunkStarts(path, every);
        ASSERT_TRUE(starts.ok()) << starts.status().message();
        EXPECT_EQ((*starts)->description().format, "laz");
        EXPECT_EQ((*starts)->description().declaredPoints, all.size());
        EXPECT_EQ((*starts)->description().scalars.size(), (*whole)->description().scalars.size());
        const std::vector<InputPoint> read = readPoints(**starts);
        ASSERT_EQ(read.size(), cuts->size());
        for (size_t k = 0; k < read.size(); ++k) ASSERT_TRUE(samePoint(read[k], all[(*cuts)[k].record])) << "chunk " << k;
    }
    auto las = openLasChunkStarts(test::dataFile("autzen_trim.las"));
    ASSERT_TRUE(las.ok());
    EXPECT_EQ(readPoints(**las).size(), 110000u);
}

// A LAS, a LAZ and a COPC file (variable chunks) read as runs between its
// cuts, each run's reader opened on its own: in order, the same points as
// one read of the whole file. Runs that a LAZ file cannot start or end at are
// refused, naming the records.
TEST(LazPcd, RunsBetweenCutsReadTheWholeFile) {
    REQUIRE_DATA();
    for (const char* f : {"autzen_trim.las", "lone-star.laz", "lion_takanawa.copc.laz"}) {
        SCOPED_TRACE(f);
        const std::string path = test::dataFile(f);
        auto cuts = lasCuts(path);
        ASSERT_TRUE(cuts.ok()) << cuts.status().message();
        ASSERT_GE(cuts->size(), 2u);
        EXPECT_EQ(cuts->front().record, 0u);
        for (size_t k = 1; k < cuts->size(); ++k) {
            EXPECT_GT((*cuts)[k].record, (*cuts)[k - 1].record);
            EXPECT_GT((*cuts)[k].byte, (*cuts)[k - 1].byte);
        }
        EXPECT_LT(cuts->back().byte, fs::file_size(path));
        auto whole = openLasReader(path, 2);
        ASSERT_TRUE(whole.ok());
        const std::vector<InputPoint> all = readPoints(**whole);
        // Runs from cut 0 to 1, 1 to 3, 3 to the end (or 1 to the end).
        std::vector<uint64_t> bounds = {0, (*cuts)[1].record};
        if (cuts->size() > 3) bounds.push_back((*cuts)[3].record);
        bounds.push_back(0);
        std::vector<InputPoint> runs;
        for (size_t i = 0; i + 1 < bounds.size(); ++i) {
            auto r = openLasReader(path, 2, {}, {bounds[i], bounds[i + 1]});
            ASSERT_TRUE(r.ok()) << r.status().message();
            const uint64_t end = bounds[i + 1] ? bounds[i + 1] : all.size();
            EXPECT_EQ((*r)->description().declaredPoints, end - bounds[i]);
            const std::vector<InputPoint> run = readPoints(**r);
            EXPECT_EQ(run.size(), end - bounds[i]);
            runs.insert(runs.end(), run.begin(), run.end());
        }
        ASSERT_EQ(runs.size(), all.size());
        for (size_t i = 0; i < all.size(); ++i) ASSERT_TRUE(samePoint(runs[i], all[i])) << "point " << i;
        auto past = openLasReader(path, 1, {}, {0, all.size() + 1});
        ASSERT_FALSE(past.ok());
        EXPECT_NE(past.status().message().find("declares " + std::to_string(all.size())), std::string::npos) << past.status().message();
        if (std::string(f).ends_with(".laz")) {
            auto inside = openLasReader(path, 1, {}, {(*cuts)[1].record + 1, 0});
            ASSERT_FALSE(inside.ok());
            EXPECT_NE(inside.status().message().find("not a run of whole chunks"), std::string::npos) << inside.status().message();
        }
    }
}

// A file scanned in two runs and merged as one source: its colour depth is
// judged over the whole file, as one scan judges it. Colours under 256 in a
// 16-bit field are 8-bit values (scaled by 257) only if no point of the file
// is over 255.
TEST(LazPcd, ColoursOfAFileScannedInRunsAreJudgedWhole) {
    test::TempDir dir;
    const uint32_t count = 3 * uint32_t(kLasCutRecords);
    struct Case {
        const char* name;
        uint16_t (*color)(uint32_t);
        double scale;  // what the whole file's values call for
        int bits;
    };
    const Case cases[] = {
        // 1..255, then 8-bit codes c·257 or 1000..1006: 16-bit values, stored as they are.
        {"small then codes", [](uint32_t i) { return uint16_t(i < kLasCutRecords ? i % 256 : (i % 256) * 257); }, 1, 16},
        {"large then small", [](uint32_t i) { return uint16_t(i < kLasCutRecords ? 1000 + i % 7 : i % 256); }, 1, 16},
        // Nothing over 255: 8-bit values in the 16-bit field.
        {"all small", [](uint32_t i) { return uint16_t(i % 256); }, 257, 8},
        // 0 and c·257: 8-bit codes already scaled, so 8 bits stored and no scale.
        {"zero then 8-bit codes", [](uint32_t i) { return uint16_t(i < kLasCutRecords ? 0 : (i % 256) * 257); }, 1, 8},
    };
    for (const auto& [name, color, scale, bits] : cases) {
        SCOPED_TRACE(name);
        const std::string path = dir.file("c.las");
        test::writeFile(path, lasWithColors(count, color));
        InputOptions options;
        options.paths = {path};
        auto whole = scanInputs(options, [](uint64_t) {});
        ASSERT_TRUE(whole.ok()) << whole.status().message();
        std::vector<InputStats> parts;
        for (auto [begin, end] : {std::pair<uint64_t, uint64_t>{0, kLasCutRecords}, {kLasCutRecords, 0}}) {
            options.firstBegin = begin;
            options.lastEnd = end;
            auto part = scanInputs(options, [](uint64_t) {});
            ASSERT_TRUE(part.ok()) << part.status().message();
            parts.push_back(std::move(*part));
        }
        const InputStats merged = mergeInputStats(std::move(parts), {false, true});
        ASSERT_EQ(merged.sources.size(), 1u);
        const SourceStats &a = merged.sources[0], &b = whole->sources[0];
        EXPECT_EQ(a.points, count);
        EXPECT_EQ(a.description.declaredPoints, count);
        EXPECT_EQ(a.colorMax, b.colorMax);
        EXPECT_EQ(a.colors8Bit, b.colors8Bit);
        EXPECT_EQ(a.colorScale, b.colorScale);
        EXPECT_EQ(merged.colorBits, whole->colorBits);
        EXPECT_EQ(merged.bounds.min, whole->bounds.min);
        EXPECT_EQ(merged.bounds.max, whole->bounds.max);
        EXPECT_EQ(a.colorScale, scale);
        EXPECT_EQ(merged.colorBits, bits);
    }
}

TEST(LazPcd, SharedFilesMatchProvenance) {
    REQUIRE_DATA();
    for (const Expected& e : kFiles) {
        SCOPED_TRACE(e.file);
        auto r = openAny(test::dataFile(e.file), 2);
        ASSERT_TRUE(r.ok()) << r.status().message();
        EXPECT_EQ((*r)->description().hasColors, e.colors);
        Scan s = scan(**r);
        EXPECT_EQ(s.points, e.points);
        EXPECT_EQ(s.skipped, e.skipped);
        EXPECT_EQ(s.anyColor, e.colors);
        for (int a = 0; a < 3; ++a) {
            EXPECT_NEAR(s.bounds.min[a], e.min[a], 1e-6) << "axis " << a;
            EXPECT_NEAR(s.bounds.max[a], e.max[a], 1e-6) << "axis " << a;
        }
    }
}

TEST(LazPcd, ParallelDecodeEqualsSequential) {
    REQUIRE_DATA();
    for (const char* f : {"lone-star.laz", "lion_takanawa.copc.laz"}) {
        auto one = openLasReader(test::dataFile(f), 1), two = openLasReader(test::dataFile(f), 2);
        ASSERT_TRUE(one.ok() && two.ok());
        Scan a = scan(**one), b = scan(**two);
        ASSERT_EQ(a.sample.size(), b.sample.size()) << f;
        for (size_t i = 0; i < a.sample.size(); ++i) ASSERT_EQ(a.sample[i], b.sample[i]) << f << " point " << i * 1000;
    }
}

TEST(LazPcd, TileSetsBuildAndReadBack) {
    REQUIRE_DATA();
    for (const Expected& e : kFiles) {
        SCOPED_TRACE(e.file);
        test::TempDir dir;
        auto r = test::run({test::binary("surfcast-build"), "-q", test::dataFile(e.file), "-o", dir.file("set")});
        ASSERT_EQ(r.exitCode, 0) << r.output;
        auto set = TilesetReader::open(dir.file("set"));
        ASSERT_TRUE(set.ok()) << set.status().message();
        EXPECT_EQ(set->info().inputPoints, e.points);
        EXPECT_EQ(set->info().colorBits != 0, e.colors);
        auto verified = verifyTileset(*set);
        EXPECT_TRUE(verified.ok()) << verified.status().message();
    }
}

TEST(LazPcd, TruncatedCopiesGiveClearErrors) {
    REQUIRE_DATA();
    for (const Expected& e : kFiles) {
        SCOPED_TRACE(e.file);
        test::TempDir dir;
        std::string bytes = test::readFile(test::dataFile(e.file));
        std::string cut = dir.file(std::string("cut-") + e.file);
        test::writeFile(cut, bytes.substr(0, bytes.size() * 6 / 10));
        auto r = test::run({test::binary("surfcast-build"), "-q", cut, "-o", dir.file("out")});
        EXPECT_EQ(r.exitCode, 1) << r.output;
        EXPECT_NE(r.output.find(cut), std::string::npos) << r.output;
        EXPECT_FALSE(fs::exists(dir.file("out")));
    }
}

TEST(LazPcd, HugeCountsInTheFileAreErrorsNotAllocations) {
    // A 1,283-byte LAZ (fuzz_read_laz's find: fuzz/regressions/read_laz)
    // whose chunk table claims 2,324,398,079 chunks: the laz crate sized a
    // vector by it (37 GB; the process aborted). The count is checked against
    // the points and the file size first.
    test::TempDir dir;
    auto r = test::run({test::binary("surfcast-build"), "-q", SURFCAST_FUZZ_REGRESSIONS "/read_laz/chunk-count-37GB.laz",
                        "-o", dir.file("out")});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("chunk-count-37GB.laz"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("the chunk table claims 2324398079 chunks"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(dir.file("out")));
    // A layered chunk (format 6-10) whose extra-bytes layer claims 4 GB in a
    // 1 KB file: the crate allocated it before reading. Layers must fit their chunk.
    auto layers = test::run({test::binary("surfcast-build"), "-q", SURFCAST_FUZZ_REGRESSIONS "/read_laz/layer-size-4GB.laz",
                             "-o", dir.file("out")});
    EXPECT_EQ(layers.exitCode, 1) << layers.output;
    EXPECT_NE(layers.output.find("chunk 0: its layers claim 4294968106 bytes, the chunk table gives the chunk 1057"),
              std::string::npos) << layers.output;
    // A 1,300-byte LAZ claiming chunks of 7.9 M points of 1,156 bytes: the
    // reader sized one read's buffer by a whole chunk (9 GB). Reads are
    // capped at 256 MB of decompressed points; the data then runs out.
    auto chunk = test::run({test::binary("surfcast-build"), "-q", SURFCAST_FUZZ_REGRESSIONS "/read_laz/huge-chunk-size.laz",
                            "-o", dir.file("out")});
    EXPECT_EQ(chunk.exitCode, 1) << chunk.output;
    EXPECT_NE(chunk.output.find("huge-chunk-size.laz: LAZ data, points 0-"), std::string::npos) << chunk.output;
    if (test::kRssMeaningful) {
        EXPECT_LT(chunk.peakRss, uint64_t(400) << 20) << chunk.output;
    }
    EXPECT_FALSE(fs::exists(dir.file("out")));
}

TEST(LazPcd, WrongCountsAndFieldsGiveClearErrors) {
    REQUIRE_DATA();
    test::TempDir dir;
    // LAZ with fixed-size chunks: the legacy count at byte 107 raised.
    std::string laz = test::readFile(test::dataFile("lone-star.laz"));
    uint32_t more = 600000;
    std::memcpy(laz.data() + 107, &more, 4);
    test::writeFile(dir.file("count.laz"), laz);
    auto a = openLasReader(dir.file("count.laz"), 1);
    ASSERT_FALSE(a.ok());
    EXPECT_NE(a.status().message().find("declares 600000 points"), std::string::npos) << a.status().message();
    // COPC (variable chunks): the 64-bit count at byte 247 lowered.
    std::string copc = test::readFile(test::dataFile("lion_takanawa.copc.laz"));
    uint64_t fewer = 1000;
    std::memcpy(copc.data() + 247, &fewer, 8);
    test::writeFile(dir.file("count.copc.laz"), copc);
    auto b = openLasReader(dir.file("count.copc.laz"), 2);
    ASSERT_FALSE(b.ok());
    EXPECT_NE(b.status().message().find("chunk table holds 341989"), std::string::npos) << b.status().message();
    // PCD: POINTS that is not WIDTH x HEIGHT, a short binary DATA, an unknown type.
    std::string head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 10\nHEIGHT 1\nPOINTS ";
    test::writeFile(dir.file("p.pcd"), head + "11\nDATA ascii\n");
    auto c = openPcdReader(dir.file("p.pcd"));
    ASSERT_FALSE(c.ok());
    EXPECT_NE(c.status().message().find("WIDTH x HEIGHT"), std::string::npos);
    test::writeFile(dir.file("short.pcd"), head + "10\nDATA binary\n" + std::string(12 * 7, '\0'));
    auto d = openPcdReader(dir.file("short.pcd"));
    ASSERT_FALSE(d.ok());
    EXPECT_NE(d.status().message().find("DATA section is short"), std::string::npos) << d.status().message();
    test::writeFile(dir.file("type.pcd"), "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F Q\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n");
    auto t = openPcdReader(dir.file("type.pcd"));
    ASSERT_FALSE(t.ok());
    EXPECT_NE(t.status().message().find("unknown type Q"), std::string::npos) << t.status().message();
    // ASCII with a packed float rgb and a NaN row.
    float packed;
    uint32_t rgb = 0x00FF8001;
    std::memcpy(&packed, &rgb, 4);
    char row[64];
    std::snprintf(row, sizeof row, "%.9g", double(packed));
    test::writeFile(dir.file("rgb.pcd"), "FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n1 2 3 " +
                                             std::string(row) + "\nnan nan nan 0\n");
    auto g = openPcdReader(dir.file("rgb.pcd"));
    ASSERT_TRUE(g.ok()) << g.status().message();
    std::vector<InputPoint> pts(4);
    auto n = (*g)->read(pts.data(), pts.size());
    ASSERT_TRUE(n.ok()) << n.status().message();
    ASSERT_EQ(*n, 1u);
    EXPECT_EQ((*g)->skipped(), 1u);
    EXPECT_EQ(pts[0].color[0], 255 * 257);
    EXPECT_EQ(pts[0].color[1], 128 * 257);
    EXPECT_EQ(pts[0].color[2], 1 * 257);
}

TEST(Lzf, HandAssembledStreams) {
    test::TempDir dir;
    // "abcabcabcX": literal run "abc" (ctrl 2), back-reference of 6 bytes at
    // distance 3 (ctrl (6-2)<<5 | 0, offset byte 2), literal "X" (ctrl 0).
    const std::string stream = std::string("\x02" "abc", 4) + std::string("\x80\x02", 2) + std::string("\x00" "X", 2);
    test::writeFile(dir.file("ok.lzf"), stream);
    auto in = ByteStream::open(dir.file("ok.lzf"));
    ASSERT_TRUE(in.ok());
    LzfStream lzf(std::move(*in), stream.size(), 10);
    uint8_t out[10];
    ASSERT_TRUE(lzf.read(out, 2).ok());
    ASSERT_TRUE(lzf.skip(3).ok());
    ASSERT_TRUE(lzf.read(out + 2, 5).ok());
    EXPECT_EQ(std::string(reinterpret_cast<char*>(out), 7), "abcabcX");  // "ab" + skip "cab" + "cabcX"
    // A back-reference before the start of the output is refused.
    const std::string bad = std::string("\x00" "a", 2) + std::string("\x20\x05", 2);
    test::writeFile(dir.file("bad.lzf"), bad);
    auto in2 = ByteStream::open(dir.file("bad.lzf"));
    LzfStream lzf2(std::move(*in2), bad.size(), 4);
    auto st = lzf2.read(out, 4);
    ASSERT_FALSE(st.ok());
    EXPECT_NE(st.message().find("before the start"), std::string::npos) << st.message();
    // Truncated: the declared output is longer than the stream gives.
    auto in3 = ByteStream::open(dir.file("ok.lzf"));
    LzfStream lzf3(std::move(*in3), stream.size(), 20);
    EXPECT_FALSE(lzf3.read(out, 10).ok() && lzf3.skip(10).ok());
}
