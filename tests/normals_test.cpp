// Estimated normals (PCA + the outward rule) against the surface normals of the
// shared meshes; the fractions are recorded in docs/ARCHITECTURE.md.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "mesh_reader.h"
#include "grid_knn.h"
#include "normals.h"
#include "test_support.h"

using namespace surfcast;

namespace {
// Agreement: within 30 degrees of the mesh's vertex normal, orientation included.
const double kAgreeCos = std::cos(30.0 * 3.14159265358979 / 180.0);

double agreement(const std::string& file) {
    auto mesh = readMeshVertexNormals(test::dataFile(file));
    EXPECT_TRUE(mesh.ok());
    if (!mesh.ok()) return 0;
    std::vector<Surfel> pts(mesh->positions.size());
    Box3d box;
    for (size_t i = 0; i < pts.size(); ++i) {
        pts[i].position = mesh->positions[i];
        box.extend(mesh->positions[i]);
    }
    NormalContext ctx;
    ctx.rules = {OrientationRule{}};
    ctx.centre = (box.min + box.max) * 0.5;
    ctx.threads = 2;
    estimateNormals(pts, {}, ctx);
    size_t agree = 0, agreeUnoriented = 0, counted = 0;
    for (size_t i = 0; i < pts.size(); ++i) {
        if (length(mesh->normals[i]) < 0.5f) continue;  // isolated vertex: no mesh normal
        ++counted;
        double d = dot(pts[i].normal, mesh->normals[i]);
        if (d >= kAgreeCos) ++agree;
        if (std::fabs(d) >= kAgreeCos) ++agreeUnoriented;
    }
    double fraction = double(agree) / double(counted);
    std::printf("%s: %.1f%% of %zu estimated normals within 30 degrees of the mesh normal (%.1f%% up to orientation)\n",
                file.c_str(), 100 * fraction, counted, 100.0 * double(agreeUnoriented) / double(counted));
    return fraction;
}
}  // namespace

TEST(Normals, AgreeWithMeshNormals) {
    REQUIRE_DATA();
    // Thresholds a few points under the measured values (docs/ARCHITECTURE.md).
    EXPECT_GE(agreement("bunny.ply"), 0.85);
    EXPECT_GE(agreement("horse.ply"), 0.75);  // thin legs defeat the outward rule
    EXPECT_GE(agreement("igea.ply"), 0.95);
}

// Each estimated point records its own sampling for the isolation of input
// points (Surfel::scanDk): on a lattice of step a, the 8th nearest other point
// lies at a·√2 (4 at a, then 4 at a·√2) and none off the plane. A point that
// came with its normal is not measured.
TEST(Normals, EachEstimatedPointRecordsItsDkAndSpread) {
    constexpr double a = 0.1;
    std::vector<Surfel> pts;
    for (int i = 0; i < 30; ++i)
        for (int j = 0; j < 30; ++j) {
            Surfel s;
            s.position = {i * a, j * a, 5.0};
            pts.push_back(s);
        }
    pts[0].normal = {0, 0, 1};  // given: not estimated, not measured
    // An update's decoded point whose normal the build estimated: measured
    // again against its kept normal, tilted here so that the offsets of its
    // 8 nearest are 0.6·Δy: √(0.36 · 6a² / 8) / (a·√2) = 0.3674.
    const size_t kept = 5 * 30 + 5;
    pts[kept].normal = {0, 0.6f, 0.8f};
    pts[kept].scanDk = kScanDkToMeasure;
    NormalContext ctx;
    ctx.rules = {OrientationRule{std::nullopt, true}};
    ctx.threads = 2;
    estimateNormals(pts, {}, ctx);
    EXPECT_EQ(pts[0].scanDk, -1.f);
    EXPECT_EQ(pts[kept].normal, (Vec3f{0, 0.6f, 0.8f}));
    EXPECT_NEAR(pts[kept].scanDk, a * std::sqrt(2.0), 1e-5);
    EXPECT_NEAR(pts[kept].scanSpread * kScanSpreadUnit, std::sqrt(0.36 * 6 / 8) / std::sqrt(2.0), 2e-4);
    size_t interior = 0;
    for (size_t p = 0; p < pts.size(); ++p) {
        const int i = int(p / 30), j = int(p % 30);
        if (i < 2 || j < 2 || i > 27 || j > 27 || p == kept) continue;
        ++interior;
        EXPECT_NEAR(pts[p].scanDk, a * std::sqrt(2.0), 1e-5) << "point " << p;
        EXPECT_EQ(pts[p].scanSpread, 0) << "point " << p;
    }
    EXPECT_EQ(interior, 26u * 26u - 1);

    // Heights alternating by h (a checkerboard): the 4 nearest, beside, lie h
    // above or below, the next 4, diagonal at a·√2, at the same height. Fitted
    // to 13 points (the point and the rings at a, a·√2 and 2a: symmetric, so
    // the plane is level), the offsets from the point along the normal are h
    // for 4 of the 8 nearest and 0 for the others: spread = √(4h²/8) / (a·√2)
    // = h / 2a.
    constexpr double h = 0.02;
    for (size_t p = 0; p < pts.size(); ++p) {
        const int i = int(p / 30), j = int(p % 30);
        pts[p].position.z = 5.0 + ((i + j) % 2 ? h : 0);
        pts[p].normal = {};
    }
    ctx.k = 13;
    estimateNormals(pts, {}, ctx);
    for (size_t p = 0; p < pts.size(); ++p) {
        const int i = int(p / 30), j = int(p % 30);
        if (i < 2 || j < 2 || i > 27 || j > 27) continue;
        const double d8 = a * std::sqrt(2.0);
        EXPECT_NEAR(pts[p].scanDk, d8, 1e-5) << "point " << p;
        EXPECT_NEAR(pts[p].scanSpread * kScanSpreadUnit, h / (2 * a), 2e-4) << "point " << p;
    }
}

TEST(Normals, PlaneFacesTheScanOrigin) {
    std::vector<Surfel> pts;
    for (int i = 0; i < 30; ++i)
        for (int j = 0; j < 30; ++j) {
            Surfel s;
            s.position = {i * 0.1, j * 0.1, 0.002 * ((i * 7 + j * 3) % 5)};
            pts.push_back(s);
        }
    NormalContext ctx;
    OrientationRule below;
    below.scanOrigin = Vec3d{1.5, 1.5, -10};
    ctx.rules = {below};
    estimateNormals(pts, {}, ctx);
    for (const Surfel& s : pts) EXPECT_LT(s.normal.z, -0.95f);
    for (Surfel& s : pts) s.normal = {};
    ctx.rules = {OrientationRule{std::nullopt, true}};
    estimateNormals(pts, {}, ctx);
    for (const Surfel& s : pts) EXPECT_GT(s.normal.z, 0.95f);
}

// A dense patch (40,000 points 5 mm apart on a tilted plane) beside sparse
// points a thousand kilometres away: the grid's 21 bits per axis over that
// cube (0.5 m cells) cannot resolve the patch, GridKnn says so, and the
// normals come from the kd-tree instead (why: BENCHMARKS.md, "Normals of a
// dense cluster beside sparse scans"). Every patch normal is the plane's,
// (-1, 0, 2)/sqrt(5), oriented up.
TEST(Normals, ADensePatchBesideFarScansTakesTheKdTree) {
    std::vector<Surfel> pts;
    for (int i = 0; i < 200; ++i)
        for (int j = 0; j < 200; ++j) {
            Surfel s;
            s.position = {i * 0.005, j * 0.005, i * 0.0025};  // z = x / 2
            pts.push_back(s);
        }
    for (int i = 0; i < 2000; ++i) {
        Surfel s;
        s.position = {1e6 + (i % 50) * 20.0, (i / 50) * 20.0, 0};
        pts.push_back(s);
    }
    std::vector<Vec3f> frame;
    for (const Surfel& s : pts) frame.push_back(cast<float>(s.position - pts[0].position));
    EXPECT_TRUE(GridKnn(frame).tooCoarse());
    std::vector<Vec3f> patch(frame.begin(), frame.begin() + 40000);
    EXPECT_FALSE(GridKnn(patch).tooCoarse()) << "the patch alone is resolved";

    NormalContext ctx;
    ctx.rules = {OrientationRule{std::nullopt, true}};
    ctx.threads = 2;
    estimateNormals(pts, {}, ctx);
    const Vec3f plane = cast<float>(normalizeOrZero(Vec3d{-1, 0, 2}));
    for (size_t i = 0; i < 40000; ++i) ASSERT_GT(dot(pts[i].normal, plane), 0.999f) << "point " << i;
    // The kd-tree's answers give the points their d_8 too: 2 neighbours at
    // 5 mm (along y), 2 at 5.59 mm (along the slope), 4 diagonal at 7.5 mm.
    for (size_t i = 2; i < 198; ++i)
        for (size_t j = 2; j < 198; ++j) {
            const Surfel& s = pts[i * 200 + j];
            ASSERT_NEAR(s.scanDk, 0.0075f, 1e-6f) << "point " << i * 200 + j;
            ASSERT_LE(s.scanSpread, 1) << "point " << i * 200 + j;
        }
}

// The kd-tree's path (GridKnn::tooCoarse) keeps the grid's rule for stacks
// of coincident points: a point with k or more copies has them as its k
// nearest. 200,000 copies at the origin, one point 0.1 mm from them (in the
// same finest cell of a 1 km cube: the cell is overfull and not one
// position) and one 1 km away: the kd-tree alone visits every copy for each
// copy (4·10^10 distances); so it is done at once (BadInput's million
// coincident points, on the other path).
TEST(Normals, CoincidentStacksOnTheKdTreePathAreAnsweredAtOnce) {
    std::vector<Surfel> pts(200000);
    pts.emplace_back().position = {1e-4, 0, 0};
    pts.emplace_back().position = {1000, 0, 0};
    std::vector<Vec3f> frame;
    for (const Surfel& s : pts) frame.push_back(cast<float>(s.position));
    ASSERT_TRUE(GridKnn(frame).tooCoarse());
    NormalContext ctx;
    ctx.rules = {OrientationRule{std::nullopt, true}};
    ctx.threads = 2;
    estimateNormals(pts, {}, ctx);
    for (size_t i = 0; i < pts.size(); i += 997) EXPECT_NEAR(length(pts[i].normal), 1.0f, 1e-5f) << "point " << i;
}

// PCA of k neighbours (the point among them) on analytic surfaces, for the k
// the normals chart sweeps (bench/BENCHMARKS.md, "Normals on a chart"),
// against bounds derived from k and the noise. Angles unsigned: orientation
// is the rule's, not the fit's.
namespace {
double angleDeg(const Vec3f& a, const Vec3d& b) {
    return std::acos(std::min(1.0, std::fabs(dot(cast<double>(a), b)) / (length(cast<double>(a)) * length(b)))) * 180 / M_PI;
}
// The k nearest of each point among `p` (itself first, then by distance), by
// brute force: an independent search, not the estimator's grid. A smaller
// k's are the first of them.
std::vector<std::vector<size_t>> nearest(const std::vector<Vec3d>& p, int k) {
    std::vector<std::vector<size_t>> out(p.size());
    std::vector<std::pair<double, size_t>> d(p.size());
    for (size_t i = 0; i < p.size(); ++i) {
        for (size_t j = 0; j < p.size(); ++j) d[j] = {dot(p[j] - p[i], p[j] - p[i]), j};
        std::partial_sort(d.begin(), d.begin() + k, d.end());
        for (int j = 0; j < k; ++j) out[i].push_back(d[size_t(j)].second);
    }
    return out;
}
std::vector<Surfel> estimated(const std::vector<Vec3d>& p, int k) {
    std::vector<Surfel> pts(p.size());
    for (size_t i = 0; i < p.size(); ++i) pts[i].position = p[i];
    NormalContext ctx;
    ctx.rules = {OrientationRule{std::nullopt, true}};
    ctx.k = k;
    ctx.threads = 2;
    estimateNormals(pts, {}, ctx);
    return pts;
}
}  // namespace

TEST(Normals, PcaOnAPlaneASphereAndAThinCylinderKeepsToItsBounds) {
    constexpr double s = 0.01;  // sampling step
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> jitter(-0.25 * s, 0.25 * s);
    std::normal_distribution<double> noise(0, 0.25 * s);
    std::vector<Vec3d> plane, noisy;
    for (int i = 0; i < 60; ++i)
        for (int j = 0; j < 60; ++j) {
            plane.push_back({i * s + jitter(rng), j * s + jitter(rng), 0});
            noisy.push_back({plane.back().x, plane.back().y, noise(rng)});
        }
    // The sphere (radius 20 s, a Fibonacci lattice about s apart) and the
    // cylinder (radius 3 s, rings s apart).
    constexpr double R = 20 * s, r = 3 * s;
    std::vector<Vec3d> sphere, cylinder;
    const int m = int(4 * M_PI * R * R / (s * s));
    for (int i = 0; i < m; ++i) {
        const double z = 1 - 2 * (i + 0.5) / m, t = M_PI * (1 + std::sqrt(5.0)) * (i + 0.5);
        sphere.push_back(Vec3d{std::cos(t) * std::sqrt(1 - z * z), std::sin(t) * std::sqrt(1 - z * z), z} * R);
    }
    const int around = int(std::lround(2 * M_PI * r / s));
    for (int h = 0; h < 60; ++h)
        for (int a = 0; a < around; ++a) {
            const double t = 2 * M_PI * (a + 0.5 * (h % 2)) / around;
            cylinder.push_back({r * std::cos(t), r * std::sin(t), h * s});
        }
    const auto sphereNear = nearest(sphere, 16), cylinderNear = nearest(cylinder, 16), noisyNear = nearest(noisy, 16);
    for (int k : {6, 8, 10, 12, 16}) {
        SCOPED_TRACE("k = " + std::to_string(k));
        // A plane without noise: exact but for float rounding.
        for (const Surfel& e : estimated(plane, k)) ASSERT_LT(angleDeg(e.normal, {0, 0, 1}), 0.01);
        // Curved, without noise: the neighbours of a point lie within d_k of
        // it, so their normals within asin(d_k / radius) of its own, and the
        // plane fitted to points of a convex patch tilts no further than the
        // normals they span.
        auto curved = [&](const std::vector<Vec3d>& p, const std::vector<std::vector<size_t>>& near, double radius, auto trueNormal) {
            const auto e = estimated(p, k);
            for (size_t i = 0; i < p.size(); ++i) {
                const double dk = length(p[near[i][size_t(k - 1)]] - p[i]);
                ASSERT_LE(angleDeg(e[i].normal, trueNormal(p[i])), std::asin(std::min(1.0, dk / radius)) * 180 / M_PI) << "point " << i;
            }
        };
        curved(sphere, sphereNear, R, [](const Vec3d& q) { return normalizeOrZero(q); });
        curved(cylinder, cylinderNear, r, [](const Vec3d& q) { return normalizeOrZero(Vec3d{q.x, q.y, 0}); });
        // Noise of sd σ along the normal: a plane fitted by least squares to
        // points with in-plane second moments Sxx, Syy about their centroid
        // tilts with variance σ²/Sxx and σ²/Syy along the two axes (the
        // slopes' standard errors), so its RMS tilt over the points is
        // sqrt(mean(σ²(1/Sxx + 1/Syy))). Within 1.2 times that: PCA fits
        // across the noise too (total least squares, not ordinary), and its
        // neighbours are the noisy points' (within 5 % of it at every k here).
        const auto e = estimated(noisy, k);
        double expected = 0, got = 0;
        size_t n = 0;
        for (size_t i = 0; i < noisy.size(); ++i) {
            const std::vector<size_t> near(noisyNear[i].begin(), noisyNear[i].begin() + k);
            double mx = 0, my = 0;
            for (size_t j : near) mx += noisy[j].x / k, my += noisy[j].y / k;
            double sxx = 0, syy = 0;
            for (size_t j : near) sxx += (noisy[j].x - mx) * (noisy[j].x - mx), syy += (noisy[j].y - my) * (noisy[j].y - my);
            const double sigma = 0.25 * s, tilt = angleDeg(e[i].normal, {0, 0, 1}) * M_PI / 180;
            expected += sigma * sigma * (1 / sxx + 1 / syy), got += tilt * tilt, ++n;
        }
        EXPECT_LE(std::sqrt(got / n), 1.2 * std::sqrt(expected / n));
        std::printf("k = %d: noisy plane RMS tilt %.2f°, least squares predicts %.2f°\n", k, std::sqrt(got / n) * 180 / M_PI,
                    std::sqrt(expected / n) * 180 / M_PI);
    }
}
