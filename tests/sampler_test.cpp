#include <gtest/gtest.h>

#include <cmath>

#include "sampler.h"

using namespace surfcast;

TEST(Sampler, OneSurfelPerOccupiedCell) {
    // 8x8 cells of size 1 on the plane z = 0.3, each with 4x4 jittered points.
    std::vector<Surfel> pts;
    for (int i = 0; i < 32; ++i)
        for (int j = 0; j < 32; ++j) {
            Surfel s;
            s.position = {(i + 0.5) / 4.0 + 0.01 * std::sin(i * 7.0 + j), (j + 0.5) / 4.0, 0.3};
            s.normal = {0, 0, 1};
            s.color[0] = 1000;
            s.color[1] = 2000;
            s.color[2] = 3000;
            pts.push_back(s);
        }
    SampleGrid g{{0, 0, 0}, 1.0, 8};
    auto out = resample(pts, g);
    ASSERT_EQ(out.size(), 64u);
    double total = 0;
    for (const Surfel& s : out) {
        total += s.count;
        EXPECT_EQ(s.count, 16);
        // Position: an input point nearest the centroid (cell centre): one of
        // the four inner points, at (±1/8, ±1/8) from the centre.
        double cx = std::floor(s.position.x) + 0.5, cy = std::floor(s.position.y) + 0.5;
        EXPECT_NEAR(std::fabs(s.position.y - cy), 0.125, 1e-12);
        EXPECT_NEAR(std::fabs(s.position.x - cx), 0.125, 0.011);
        // Constant colour survives the prefilter exactly.
        EXPECT_EQ(s.color[0], 1000);
        EXPECT_EQ(s.color[2], 3000);
        EXPECT_EQ(s.normal, (Vec3f{0, 0, 1}));
    }
    EXPECT_EQ(total, 1024);
}

TEST(Sampler, PrefilterBlursAStepEdgeSymmetrically) {
    // A black/white edge at x = 4: the surfels next to it move toward grey by
    // the same amount from either side. 7x7 points per cell put a point on
    // each cell's centroid, so surfels sit at the cell centres.
    std::vector<Surfel> pts;
    for (int i = 0; i < 56; ++i)
        for (int j = 0; j < 7; ++j) {
            Surfel s;
            s.position = {(i + 0.5) / 7.0, (j + 0.5) / 7.0, 0};
            uint16_t v = i < 28 ? 0 : 65535;
            s.color[0] = s.color[1] = s.color[2] = v;
            pts.push_back(s);
        }
    auto out = resample(pts, SampleGrid{{0, 0, 0}, 1.0, 8});
    ASSERT_EQ(out.size(), 8u);
    std::sort(out.begin(), out.end(), [](const Surfel& a, const Surfel& b) { return a.position.x < b.position.x; });
    EXPECT_NEAR(out[3].position.x, 3.5, 1e-12);
    EXPECT_EQ(out[0].color[0], 0);
    EXPECT_EQ(out[7].color[0], 65535);
    EXPECT_GT(out[3].color[0], 0);
    EXPECT_LT(out[4].color[0], 65535);
    EXPECT_NEAR(double(out[3].color[0]), 65535.0 - out[4].color[0], 2.0);
}
