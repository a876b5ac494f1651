#include <gtest/gtest.h>

#include <algorithm>
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
    // Counted without resampling: 64 cells of size 1, 16 of size 2 (the grid
    // origin on the points' corner), 9 of size 3 (8 / 3 rounds up), and the
    // points beyond a 2-cell grid clamped into its border cells.
    EXPECT_EQ(occupiedCells(pts, g), 64u);
    EXPECT_EQ(occupiedCells(pts, SampleGrid{{0, 0, 0}, 2.0, 4}), 16u);
    EXPECT_EQ(occupiedCells(pts, SampleGrid{{0, 0, 0}, 3.0, 3}), 9u);
    EXPECT_EQ(occupiedCells(pts, SampleGrid{{0, 0, 0}, 1.0, 2}), 4u);
    EXPECT_EQ(resample(pts, SampleGrid{{0, 0, 0}, 3.0, 3}).size(), 9u);
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

// Categorical attributes take the majority of the input points behind a cell
// (surfel counts, not surfels), the lowest value on a tie; intensity is
// prefiltered like colour, so a constant one survives exactly.
TEST(Sampler, MajorityClassAndReturnsPrefilteredIntensity) {
    auto surfel = [](double x, uint8_t cls, float count, uint8_t returns) {
        Surfel s;
        s.position = {x, 0.5, 0.5};
        s.normal = {0, 0, 1};
        s.classification = cls;
        s.count = count;
        s.returns = returns;
        s.intensity = 700;
        return s;
    };
    // Cell 0: class 5 once (weight 3) against class 2 twice (weight 1 each):
    // the weight wins, though the surfel nearest the centroid (x = 0.48) is a 2. Cell 2 (far from cell 0, outside its prefilter): a tie
    // between classes 9 and 3, and between returns 0x21 and 0x12.
    std::vector<Surfel> pts = {surfel(0.2, 2, 1, 0x12), surfel(0.4, 2, 1, 0x12), surfel(0.6, 5, 3, 0x11),
                               surfel(20.3, 9, 1, 0x21), surfel(20.7, 3, 1, 0x12)};
    SampleGrid g{{0, 0, 0}, 1.0, 32};
    auto out = resample(pts, g);
    ASSERT_EQ(out.size(), 2u);
    std::sort(out.begin(), out.end(), [](const Surfel& a, const Surfel& b) { return a.position.x < b.position.x; });
    EXPECT_EQ(out[0].classification, 5);
    EXPECT_EQ(out[0].returns, 0x11);
    EXPECT_EQ(out[1].classification, 3);
    EXPECT_EQ(out[1].returns, 0x12);
    EXPECT_EQ(out[0].intensity, 700);
    EXPECT_EQ(out[1].intensity, 700);
}
