// The grid k-nearest search (grid_knn.h) against FLANN's exact kd-tree
// (neighbours.h): the same k-th-neighbour distances on real scans and on the
// layouts that push it to coarser levels (outliers, far clusters, duplicates,
// fewer points than k).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <random>

#include "grid_knn.h"
#include "las_reader.h"
#include "neighbours.h"
#include "pcd_reader.h"
#include "ply_reader.h"
#include "test_support.h"

using namespace surfcast;

namespace {

// Float rounding: both compute |a - b|² in float from the same float
// coordinates, summing in possibly different orders (a few ulps).
constexpr float kRelativeTolerance = 1e-5f;

// Compares every point's k nearest distances (all k of them, not only the
// k-th) with FLANN's, nearest first.
// Returns how many points were compared.
size_t compareWithFlann(const std::vector<Vec3f>& points, int k) {
    GridKnn grid(points);
    NeighbourIndex flann(points, 2);
    std::vector<int> idx;
    std::vector<float> d2;
    flann.knn(points.data(), points.size(), k, &idx, &d2);
    const size_t kk = points.empty() ? 0 : d2.size() / points.size();
    std::vector<std::vector<float>> ours(points.size());
    std::atomic<size_t> visited{0};
    grid.forEach(k, 2, {}, [&](uint32_t q, const GridKnn::Neighbours& n) {
        const auto nbr = n.indices;
        const auto dist2 = n.dist2;
        EXPECT_EQ(nbr.size(), dist2.size());
        EXPECT_EQ(nbr.size(), n.positions.size());
        for (size_t j = 0; j < nbr.size(); ++j) {
            // The distances and positions reported are those of the indices reported.
            EXPECT_EQ(n.positions[j], points[nbr[j]]);
            Vec3f v = points[nbr[j]] - points[q];
            EXPECT_NEAR(dot(v, v), dist2[j], 1e-6f * std::max(1.f, dist2[j]));
        }
        ours[q].assign(dist2.begin(), dist2.end());
        visited++;
    });
    EXPECT_EQ(visited.load(), points.size());
    size_t mismatches = 0;
    for (size_t q = 0; q < points.size(); ++q) {
        EXPECT_EQ(ours[q].size(), kk) << "query " << q;
        if (ours[q].size() != kk) continue;
        for (size_t j = 0; j < kk; ++j) {
            float a = ours[q][j], b = d2[q * kk + j];
            if (std::fabs(a - b) > kRelativeTolerance * std::max(a, b) + 1e-30f && mismatches++ < 5)
                ADD_FAILURE() << "query " << q << " neighbour " << j << ": grid " << a << ", FLANN " << b;
        }
    }
    EXPECT_EQ(mismatches, 0u);
    return points.size();
}

std::vector<Vec3f> readAll(PointReader& reader) {
    std::vector<InputPoint> buf(65536);
    std::vector<Vec3d> raw;
    while (true) {
        auto n = reader.read(buf.data(), buf.size());
        EXPECT_TRUE(n.ok()) << n.status().message();
        if (!n.ok() || *n == 0) break;
        for (size_t i = 0; i < *n; ++i) raw.push_back(buf[i].position);
    }
    std::vector<Vec3f> out;
    for (const Vec3d& p : raw) out.push_back(cast<float>(p - raw[0]));
    return out;
}

}  // namespace

TEST(GridKnn, SameDistancesAsFlannOnRealScans) {
    REQUIRE_DATA();
    struct Scan {
        std::string file;
        Result<std::unique_ptr<PointReader>> (*open)(const std::string&);
    };
    auto las = [](const std::string& p) { return openLasReader(p); };
    auto pcd = [](const std::string& p) { return openPcdReader(p); };
    auto ply = [](const std::string& p) { return openPlyReader(p); };
    const Scan scans[] = {{"lion_takanawa.copc.laz", las}, {"CSite1_red1-utm.pcd", pcd}, {"Megaplot.laz", las},
                          {"bunny.ply", ply}, {"table_scene_mug_stereo_textured.pcd", pcd}};
    for (const Scan& s : scans) {
        auto reader = s.open(test::dataFile(s.file));
        ASSERT_TRUE(reader.ok()) << reader.status().message();
        std::vector<Vec3f> pts = readAll(**reader);
        ASSERT_GT(pts.size(), 30000u) << s.file;
        SCOPED_TRACE(s.file);
        compareWithFlann(pts, 16);
        compareWithFlann(pts, 9);
    }
}

TEST(GridKnn, OutliersFarClustersAndDuplicates) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(0, 1);
    std::vector<Vec3f> pts;
    // A dense plane, a second one far away, a sparse cloud of outliers around
    // both, and stacks of identical points.
    for (int i = 0; i < 20000; ++i) pts.push_back({u(rng), u(rng), 0.01f * u(rng)});
    for (int i = 0; i < 5000; ++i) pts.push_back({500 + u(rng), 300 + u(rng), 200 + u(rng)});
    for (int i = 0; i < 200; ++i) pts.push_back({600 * u(rng) - 50, 400 * u(rng) - 50, 300 * u(rng) - 50});
    for (int i = 0; i < 40; ++i) pts.push_back({0.5f, 0.5f, 0.5f});
    for (int i = 0; i < 3; ++i) pts.push_back({-1000, -1000, -1000});
    compareWithFlann(pts, 16);
}

// Stacks of coincident points whose copies alternate in the input with those
// of a second stack a hair away (in the same finest cell): of k - 1, k and
// k + 1 copies against FLANN; then two stacks of 200,000, every third point
// queried, each at distance 0 from all its k nearest. Those must not cost n²
// distances (hours); ctest's timeout is what fails if they do.
TEST(GridKnn, InterleavedStacksOfCoincidentPoints) {
    const int k = 16;
    const Vec3f hair{1e-7f, 0, 0};
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0, 1);
    std::vector<Vec3f> pts;
    for (int i = 0; i < 3000; ++i) pts.push_back({u(rng), u(rng), 0.01f * u(rng)});
    for (int copies : {k - 1, k, k + 1}) {
        const Vec3f at{u(rng), u(rng), 0.5f};
        for (int i = 0; i < copies; ++i) {
            pts.push_back(at);
            pts.push_back(at + hair);
        }
    }
    compareWithFlann(pts, k);

    std::vector<Vec3f> stacks;
    for (int i = 0; i < 200000; ++i) {
        stacks.push_back({0.25f, 0.5f, 0.75f});
        stacks.push_back(Vec3f{0.25f, 0.5f, 0.75f} + hair);
    }
    // Corners (not queried: indices 1 and 2 mod 3) that make the grid's cube a
    // unit one, whose finest cells (2^-21) hold both stacks.
    stacks.push_back({0, 0, 0});
    stacks.push_back({1, 1, 1});
    GridKnn grid(stacks);
    std::atomic<size_t> visited{0}, atZero{0};
    grid.forEach(k, 2, [](uint32_t i) { return i % 3 == 0; }, [&](uint32_t q, const GridKnn::Neighbours& n) {
        visited++;
        bool all = n.indices.size() == size_t(k);
        for (size_t j = 0; j < n.indices.size(); ++j) all = all && n.dist2[j] == 0 && stacks[n.indices[j]] == stacks[q];
        atZero += all;
    });
    EXPECT_EQ(visited.load(), 400000u / 3 + 1);
    EXPECT_EQ(atZero.load(), visited.load());
}

TEST(GridKnn, FewerPointsThanK) {
    for (size_t n : {1, 2, 5, 15}) {
        std::vector<Vec3f> pts;
        for (size_t i = 0; i < n; ++i) pts.push_back({float(i), float(i * i % 7), 0});
        compareWithFlann(pts, 16);
    }
    GridKnn empty(std::vector<Vec3f>{});
    int calls = 0;
    empty.forEach(16, 1, {}, [&](uint32_t, const GridKnn::Neighbours&) { ++calls; });
    EXPECT_EQ(calls, 0);
}

TEST(GridKnn, OnlyWantedQueriesAreVisited) {
    std::vector<Vec3f> pts;
    for (int i = 0; i < 100; ++i)
        for (int j = 0; j < 100; ++j) pts.push_back({float(i), float(j), 0});
    GridKnn grid(pts);
    std::vector<std::atomic<int>> seen(pts.size());
    grid.forEach(4, 2, [](uint32_t i) { return i % 3 == 0; },
                 [&](uint32_t q, const GridKnn::Neighbours& n) {
                     const auto nbr = n.indices;
                     const auto d2 = n.dist2;
                     seen[q]++;
                     // On a unit lattice: the point itself, then lattice neighbours.
                     ASSERT_EQ(nbr.size(), 4u);
                     EXPECT_EQ(nbr[0], q);
                     EXPECT_EQ(d2[0], 0.f);
                     EXPECT_EQ(d2[1], 1.f);
                     EXPECT_LE(d2[3], 2.f);
                 });
    for (size_t i = 0; i < pts.size(); ++i) EXPECT_EQ(seen[i].load(), i % 3 == 0 ? 1 : 0) << i;
}
