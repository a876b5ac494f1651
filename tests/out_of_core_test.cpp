// A build with --memory well below what the input would take in memory stays
// within the budget (peak RSS of the child process, +10%).
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <random>

#include "chunker.h"
#include "octree_builder.h"
#include "test_support.h"

using namespace surfcast;

namespace {
void expectWithinBudget(uint64_t peakRss, uint64_t budget, const std::string& output) {
    if (test::kRssMeaningful) EXPECT_LE(double(peakRss), 1.10 * double(budget)) << "peak RSS " << (peakRss >> 20) << " MiB\n" << output;
    else std::printf("sanitizer build: peak RSS %llu MiB not checked\n", (unsigned long long)(peakRss >> 20));
}
}  // namespace

TEST(OutOfCore, PeakRssStaysWithinBudget) {
    test::TempDir dir;
    // In memory the build would hold about kBytesPerChunkPoint per point: ~1 GB
    // (under a sanitizer, where RSS is not checked, a third of that still
    // makes several chunks; the sanitizer stages leave this case out, and only
    // bench/case_coverage.py's asan-coverage build runs it there).
    const uint64_t points = test::kSanitized ? 1'000'000 : 3'000'000;
    const uint64_t budget = 160ull << 20;
    if (test::kRssMeaningful) {
        ASSERT_GT(points * kBytesPerChunkPoint, 4 * budget);
    }
    auto r = test::buildScene(dir.file("big"), int(points), {"--memory", "160M", "--threads", "2"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find(" chunks"), std::string::npos);
    EXPECT_EQ(r.output.find(" 1 chunks"), std::string::npos) << "the budget should have forced several chunks\n" << r.output;
    expectWithinBudget(r.peakRss, budget, r.output);
    auto v = test::run({test::binary("surfcast-build"), "--info", dir.file("big")});
    EXPECT_EQ(v.exitCode, 0) << v.output;
}

// Thousands of small LAZ files, as Potree 1.x and Entwine leave a scan:
// readers open one at a time and share one decode pool, so the budget holds
// (every file's reader, decode pool and buffer open at once would take
// 5.8 GiB for 4,234 files under a 2 GiB budget).
TEST(OutOfCore, ThousandsOfLazFilesStayWithinBudget) {
    REQUIRE_DATA();
    REQUIRE_TEST_PYTHON();
    test::TempDir dir;
    auto split = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/split_laz.py", test::dataFile("lone-star.laz"),
                            dir.file("tiles"), "--cells", "32x32x8", "--min-files", "1000"});
    ASSERT_EQ(split.exitCode, 0) << split.output;
    auto made = test::jsonLines(split.output);
    ASSERT_EQ(made.size(), 1u) << split.output;
    const uint64_t files = made[0]["files"].get<uint64_t>();
    ASSERT_GE(files, 1000u);
    ASSERT_EQ(size_t(std::distance(std::filesystem::directory_iterator(dir.file("tiles")), {})), files);

    const uint64_t budget = 128ull << 20;
    auto r = test::run({test::binary("surfcast-build"), "-q", dir.file("tiles"), "--memory", "128M", "--threads", "2",
                        "-o", dir.file("set")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    expectWithinBudget(r.peakRss, budget, r.output);
    // Every point of lone-star.laz (PROVENANCE.md: 518,862) arrived from the folder.
    EXPECT_NE(r.output.find("points in: 518862 "), std::string::npos) << r.output;
    EXPECT_EQ(r.output.find(" 1 chunks"), std::string::npos) << "the budget should have forced several chunks\n" << r.output;
    auto v = test::run({test::binary("surfcast-build"), "--info", dir.file("set")});
    EXPECT_EQ(v.exitCode, 0) << v.output;
}

// A point near any cell of a chunk's border, toward a neighbouring cell of
// another chunk, is that chunk's halo (0.001 of a cell from the neighbour's
// cell, well inside the smallest margin here, 4/128 of a cell), wherever the
// layout marks cells interior to skip the search. Brute force over the 26 neighbours against fromCounts's layout,
// with chunks of many sizes next to each other and empty cells between.
TEST(OutOfCore, CellsBesideAnotherChunkSendTheirPointsToItsHalo) {
    const uint32_t n = 1u << kCountLevel;
    std::vector<uint32_t> counts(size_t(n) * n * n, 0);
    std::mt19937 random(7);
    auto index = [n](int64_t x, int64_t y, int64_t z) { return size_t((x * n + y) * n + z); };
    // A dense corner that splits down to single cells, sparse cells beside it,
    // and a block on the far side.
    for (uint32_t x = 0; x < 24; ++x)
        for (uint32_t y = 0; y < 24; ++y)
            for (uint32_t z = 0; z < 24; ++z) counts[index(x, y, z)] = random() % 4 == 0 ? 0 : 1 + random() % (x < 8 ? 900 : 60);
    for (uint32_t x = 100; x < 128; ++x)
        for (uint32_t y = 60; y < 70; ++y) counts[index(x, y, 127)] = 50;
    const double rootEdge = 128.0;  // one unit a cell
    ChunkLayout layout = ChunkLayout::fromCounts(counts, 2000, rootEdge, 128);
    ASSERT_GT(layout.chunks().size(), 50u);

    std::vector<int> halo;
    size_t borderCells = 0, probes = 0;
    for (int64_t x = 0; x < n; ++x)
        for (int64_t y = 0; y < n; ++y)
            for (int64_t z = 0; z < n; ++z) {
                const Vec3d centre{x + 0.5, y + 0.5, z + 0.5};
                const int own = layout.chunkOf(centre);
                if (own < 0) continue;
                bool border = false;
                for (int dx = -1; dx <= 1; ++dx)
                    for (int dy = -1; dy <= 1; ++dy)
                        for (int dz = -1; dz <= 1; ++dz) {
                            const int64_t c[3] = {x + dx, y + dy, z + dz};
                            if ((dx | dy | dz) == 0 || std::any_of(c, c + 3, [n](int64_t v) { return v < 0 || v >= n; })) continue;
                            const Vec3d other{c[0] + 0.5, c[1] + 0.5, c[2] + 0.5};
                            const int id = layout.chunkOf(other);
                            if (id < 0 || id == own) continue;
                            border = true;
                            // The cell's point nearest the neighbour, a hair inside.
                            const Vec3d p{centre.x + dx * 0.499, centre.y + dy * 0.499, centre.z + dz * 0.499};
                            layout.haloChunksOf(p, &halo);
                            ++probes;
                            ASSERT_NE(std::find(halo.begin(), halo.end(), id), halo.end())
                                << "cell " << x << "," << y << "," << z << " (chunk " << own << ") beside chunk " << id;
                        }
                borderCells += border;
            }
    EXPECT_GT(borderCells, 1000u);
    std::printf("%zu chunks, %zu cells beside another chunk, %zu probes\n", layout.chunks().size(), borderCells, probes);
}
