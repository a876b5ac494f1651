// A build with --memory well below what the input would take in memory stays
// within the budget (peak RSS of the child process, +10%).
#include <gtest/gtest.h>

#include "octree_builder.h"
#include "test_support.h"

using namespace surfcast;

TEST(OutOfCore, PeakRssStaysWithinBudget) {
    test::TempDir dir;
    const uint64_t points = 3'000'000;
    const uint64_t budget = 160ull << 20;
    // In memory the build would hold about kBytesPerChunkPoint per point: ~1 GB.
    ASSERT_GT(points * kBytesPerChunkPoint, 4 * budget);
    auto r = test::buildScene(dir.file("big"), int(points), {"--memory", "160M", "--threads", "2"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find(" chunks"), std::string::npos);
    EXPECT_EQ(r.output.find(" 1 chunks"), std::string::npos) << "the budget should have forced several chunks\n" << r.output;
    EXPECT_LE(double(r.peakRss), 1.10 * double(budget)) << "peak RSS " << (r.peakRss >> 20) << " MiB\n" << r.output;
    auto v = test::run({test::binary("surfcast-build"), "--info", dir.file("big")});
    EXPECT_EQ(v.exitCode, 0) << v.output;
}
