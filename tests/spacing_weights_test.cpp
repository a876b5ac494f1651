// h, per-surfel radii and analytic weights against hand-derived values on a
// square lattice (docs/ARCHITECTURE.md, "Spacing" and "Weights").
#include <gtest/gtest.h>

#include <cmath>

#include "level_attributes.h"
#include "mesh_reader.h"
#include "neighbours.h"
#include "normals.h"
#include "tileset_format.h"
#include "test_support.h"

using namespace surfcast;

namespace {
constexpr double kA = 0.01;  // lattice spacing

// Lattice points (i, j) for i, j in [lo, hi], on z = 0 with normal +z.
std::vector<Surfel> lattice(int lo, int hi, bool inner, int ring, Vec3f normal = {0, 0, 1}, double z = 0) {
    std::vector<Surfel> out;
    for (int i = lo; i <= hi; ++i)
        for (int j = lo; j <= hi; ++j) {
            bool isInner = i >= lo + ring && i <= hi - ring && j >= lo + ring && j <= hi - ring;
            if (isInner != inner) continue;
            Surfel s;
            s.position = {i * kA, j * kA, z};
            s.normal = normal;
            out.push_back(s);
        }
    return out;
}
}  // namespace

TEST(Spacing, LatticeSpacingIsEighthNeighbourDistance) {
    // 21x21 own surfels, surrounded by a 4-wide halo: no border effects.
    std::vector<Surfel> own = lattice(-14, 14, true, 4), halo = lattice(-14, 14, false, 4);
    LevelNode node;
    node.surfels = own;
    LevelNode* nodes[] = {&node};
    LevelParams p;
    p.cutoff = 1.2;  // puts the boundary between |u|² = 4a² (inside) and 5a² (outside)
    computeLevelAttributes(nodes, halo, p);
    // 8th neighbour on a square lattice: 4 at a, then 4 at a·√2.
    EXPECT_NEAR(node.h, kA * std::sqrt(2.0), 1e-6);
    EXPECT_TRUE(node.radii.empty());
    // Weight: 1 / (1 + 4e^{-1/4} + 4e^{-1/2} + 4e^{-1}) with h² = 2a²:
    // |u|² = a² → exp(-a²/(2·2a²)) = e^{-1/4}; 2a² → e^{-1/2}; 4a² → e^{-1}.
    double expected = 1.0 / (1 + 4 * std::exp(-0.25) + 4 * std::exp(-0.5) + 4 * std::exp(-1.0));
    ASSERT_EQ(node.weights.size(), own.size());
    for (float w : node.weights) EXPECT_NEAR(w, expected, 1e-4);
}

TEST(Spacing, WithoutHaloBordersWouldInflateH) {
    // The same lattice without its halo: the 95th percentile lands on border
    // surfels whose 8th neighbour is farther. This is why chunks carry halos.
    std::vector<Surfel> own = lattice(-10, 10, true, 0);
    LevelNode node;
    node.surfels = own;
    LevelNode* nodes[] = {&node};
    computeLevelAttributes(nodes, {}, LevelParams{});
    EXPECT_GT(node.h, kA * std::sqrt(2.0) * 1.2);
}

TEST(Spacing, OutliersDoNotBlowUpH) {
    std::vector<float> dk(1000, 1.0f);
    for (int i = 0; i < 30; ++i) dk.push_back(100.0f);  // 3% isolated outliers
    SpacingResult r = spacingRule(dk, 0.5);
    EXPECT_FLOAT_EQ(r.h, 1.0f);
    EXPECT_FALSE(r.irregular);
    std::vector<float> empty;
    EXPECT_FLOAT_EQ(spacingRule(empty, 0.5).h, 0.5f);  // no neighbours: the level's cell size
}

TEST(Spacing, IrregularNodesGetPerSurfelRadii) {
    // Half the node sampled 10x denser than the other half.
    std::vector<Surfel> own;
    for (int i = 0; i < 40; ++i)
        for (int j = 0; j < 40; ++j) {
            Surfel s;
            s.normal = {0, 0, 1};
            s.position = i < 20 ? Vec3d{i * kA, j * kA, 0} : Vec3d{0.2 + (i - 20) * kA * 10, j * kA * 10, 0};
            own.push_back(s);
        }
    LevelNode node;
    node.surfels = own;
    LevelNode* nodes[] = {&node};
    computeLevelAttributes(nodes, {}, LevelParams{});
    ASSERT_EQ(node.radii.size(), own.size());
    for (size_t i = 0; i < own.size(); ++i) EXPECT_LE(node.radii[i], node.h);
    // Dense half: radius about a·√2, far below h.
    EXPECT_LT(node.radii[5 * 40 + 5], node.h / 4);
}

// Isolated surfels (level_attributes.h): drawn at rho = kIsolationSpacing
// (2) sampling cells. With the level's cell at the lattice spacing a, rho = 2a
// while the lattice's own 8th neighbour lies at a·√2 (4 at a, then 4 at a·√2),
// which fixes every expected value below by hand.
constexpr double kRho = 2 * kA;

LevelParams isolatingOn(double isolation = kDefaultIsolation) {
    LevelParams p;
    p.levelCell = kA;
    p.isolation = isolation;
    return p;
}

std::vector<Surfel> strays(int count, double height, double step) {
    std::vector<Surfel> out;
    for (int i = 0; i < count; ++i) {
        Surfel s;
        s.position = {i * step, 0.5 * step, height};
        s.normal = {0, 0, 1};
        out.push_back(s);
    }
    return out;
}

TEST(Isolation, StraysInANodeOfTheirOwnAreDrawnAtTheLevelSpacing) {
    // A lattice (with halo) and, as a second node of the level, ten strays
    // 20a above it and 20a apart: their 8th neighbours lie 20a to 160a away.
    std::vector<Surfel> own = lattice(-14, 14, true, 4), halo = lattice(-14, 14, false, 4);
    std::vector<Surfel> far = strays(10, 20 * kA, 20 * kA);
    LevelNode plane, stray;
    plane.surfels = own;
    stray.surfels = far;
    LevelNode* nodes[] = {&plane, &stray};
    computeLevelAttributes(nodes, halo, isolatingOn());
    EXPECT_NEAR(plane.h, kA * std::sqrt(2.0), 1e-6);
    EXPECT_TRUE(plane.radii.empty());  // none of it isolated: nothing narrower than h
    const float hIsolating = stray.h;
    ASSERT_EQ(stray.radii.size(), far.size());
    for (float r : stray.radii) EXPECT_NEAR(r, kRho, 1e-6);

    // Without isolation they are drawn at their 8th-neighbour distances, and
    // h, the bound level selection relies on, is the same either way.
    computeLevelAttributes(nodes, halo, isolatingOn(0));
    EXPECT_EQ(stray.h, hIsolating);
    EXPECT_GT(stray.h, 20 * kA);
    for (size_t i = 0; i < far.size(); ++i) EXPECT_GT(stray.radii.empty() ? stray.h : stray.radii[i], 20 * kA);
}

TEST(Isolation, InputPointsAreIsolatedByTheirScansOwnSampling) {
    // The ten strays of the test above as input points (cell 0) whose
    // normals were estimated, so each carries its scan's d_8 and spread
    // (Surfel::scanDk). Measured isolated (d_8 = 20a, beyond 6 rho): drawn at
    // rho, as when the level's neighbours decide. Measured inside a surface
    // (d_8 = a, no spread: the rest of their scan went to other levels), they
    // are not isolated, but the level's 8th neighbours, 20a to 160a away, still
    // cap them at isolation * rho = 12a, under their h (> 20a): a node without
    // radii would draw them at h.
    std::vector<Surfel> own = lattice(-14, 14, true, 4), halo = lattice(-14, 14, false, 4);
    std::vector<Surfel> far = strays(10, 20 * kA, 20 * kA);
    for (Surfel& s : far) s.scanDk = float(20 * kA), s.scanSpread = 0;
    LevelNode plane, stray;
    plane.surfels = own;
    stray.surfels = far;
    LevelNode* nodes[] = {&plane, &stray};
    computeLevelAttributes(nodes, halo, isolatingOn());
    ASSERT_EQ(stray.radii.size(), far.size());
    for (float r : stray.radii) EXPECT_NEAR(r, kRho, 1e-6);

    for (Surfel& s : far) s.scanDk = float(kA);
    computeLevelAttributes(nodes, halo, isolatingOn());
    EXPECT_GT(stray.h, 20 * kA);
    ASSERT_EQ(stray.radii.size(), far.size());
    for (float r : stray.radii) EXPECT_NEAR(r, kDefaultIsolation * kRho, 1e-6);
}

TEST(Isolation, HOfANodeTooLargeToQueryWholeStaysItsSamplesH) {
    // 4,000 strays scattered through a box 400a wide: more than kSpacingSamples,
    // so h comes from a strided sample. Isolating them queries the node whole
    // for their radii, which must not replace that h by the exact one.
    std::vector<Surfel> cloud;
    uint32_t seed = 11;
    auto next = [&] { return (seed = seed * 1664525u + 1013904223u) / 4294967296.0; };
    for (int i = 0; i < 4000; ++i) {
        Surfel s;
        s.position = {next() * 400 * kA, next() * 400 * kA, next() * 400 * kA};
        s.normal = {0, 0, 1};
        cloud.push_back(s);
    }
    LevelNode on, off;
    on.surfels = cloud;
    off.surfels = cloud;
    LevelNode* onNodes[] = {&on};
    LevelNode* offNodes[] = {&off};
    computeLevelAttributes(onNodes, {}, isolatingOn());
    computeLevelAttributes(offNodes, {}, isolatingOn(0));
    ASSERT_TRUE(off.radii.empty());  // regular: its h is the sample's
    EXPECT_EQ(on.h, off.h);
    ASSERT_EQ(on.radii.size(), cloud.size());
    for (float r : on.radii) EXPECT_NEAR(r, kRho, 1e-6);  // 8th neighbours about 30a away: all isolated
}

TEST(Isolation, ADensityJumpOnAPlaneIsNotIsolated) {
    // The plane sampled at a for x < 0 and at 3a beyond (a ninth of the
    // density): the sparse part's d_8 is 3·a·√2 = 2.1 rho, under 6 rho, and its
    // neighbours lie on the plane (no spread), so away from the scan's border
    // (no halo here) it is drawn at 3·a·√2, not shrunk to rho. At isolation 2
    // it would be.
    std::vector<Surfel> own;
    auto add = [&](double x, double y) {
        Surfel s;
        s.position = {x, y, 0};
        s.normal = {0, 0, 1};
        own.push_back(s);
    };
    for (int i = -30; i < 0; ++i)
        for (int j = -30; j <= 30; ++j) add(i * kA, j * kA);
    const size_t dense = own.size();
    for (int i = 0; i < 10; ++i)
        for (int j = -10; j <= 10; ++j) add((i + 0.5) * 3 * kA, j * 3 * kA);
    for (double isolation : {kDefaultIsolation, 2.0}) {
        LevelNode node;
        node.surfels = own;
        LevelNode* nodes[] = {&node};
        computeLevelAttributes(nodes, {}, isolatingOn(isolation));
        const double expected = isolation == 2.0 ? kRho : 3 * kA * std::sqrt(2.0);
        size_t interior = 0;
        for (size_t i = dense; i < own.size(); ++i) {
            const Vec3d p = own[i].position;
            if (p.x < 3 * 3 * kA || p.x > 7 * 3 * kA || std::fabs(p.y) > 7 * 3 * kA) continue;  // 3 spacings from the border
            ++interior;
            EXPECT_NEAR(node.radii.empty() ? node.h : node.radii[i], expected, 1e-6) << "surfel " << i << ", isolation " << isolation;
        }
        EXPECT_EQ(interior, 4u * 15u);
    }
}

TEST(Isolation, PointsScatteredIn3DNearTheSpacingAreIsolatedToo) {
    // Points scattered through a cube (a canopy's leaves), 400 in (20a)³, with
    // normals as the builder estimates them (PCA of 16 neighbours): their 8th
    // neighbour about 3.4a = 1.7 rho away (8 · 20a³ = 4/3 π d³), under 6 rho
    // but beyond rho, and spread off the fitted plane. Uniform points in 3D
    // spread by about 0.3 of d_8 from it (the harness's strays: a median of
    // 0.27, bench/BENCHMARKS.md, "Where real scans fail"), over
    // kScatteredSpread, so most are drawn at rho.
    std::vector<Surfel> own = lattice(-14, 14, true, 4), halo = lattice(-14, 14, false, 4);
    std::vector<Surfel> scattered;
    uint32_t seed = 7;
    auto next = [&] { return (seed = seed * 1664525u + 1013904223u) / 4294967296.0; };
    for (int i = 0; i < 400; ++i) {
        Surfel s;
        s.position = {0.5 + next() * 20 * kA, next() * 20 * kA, next() * 20 * kA};
        scattered.push_back(s);  // zero normal: estimated below
    }
    NormalContext normals;
    normals.rules = {OrientationRule{}};
    estimateNormals(scattered, {}, normals);
    LevelNode plane, cloud;
    plane.surfels = own;
    cloud.surfels = scattered;
    LevelNode* nodes[] = {&plane, &cloud};
    computeLevelAttributes(nodes, halo, isolatingOn());
    ASSERT_EQ(cloud.radii.size(), scattered.size());
    size_t atRho = 0;
    for (float r : cloud.radii) atRho += std::fabs(r - kRho) < 1e-6;
    EXPECT_GT(atRho, cloud.radii.size() / 2);
}

TEST(Weights, OppositeFacingNeighboursAreIgnored) {
    // A second lattice 1 mm behind, facing away: the visibility pass hides it,
    // so it must not change the weights of the front one.
    std::vector<Surfel> own = lattice(-14, 14, true, 4), halo = lattice(-14, 14, false, 4);
    std::vector<Surfel> back = lattice(-14, 14, true, 0, {0, 0, -1}, -0.001);
    halo.insert(halo.end(), back.begin(), back.end());
    LevelNode node;
    node.surfels = own;
    LevelNode* nodes[] = {&node};
    LevelParams p;
    p.cutoff = 1.2;
    computeLevelAttributes(nodes, halo, p);
    double expected = 1.0 / (1 + 4 * std::exp(-0.25) + 4 * std::exp(-0.5) + 4 * std::exp(-1.0));
    for (float w : node.weights) EXPECT_NEAR(w, expected, 1e-4);
}

TEST(Weights, GridSearchFindsEveryNeighbourOnARealScan) {
    // The weights' fixed-radius grid search against a brute-force sum over
    // every surfel, on the bunny's vertices (irregular, real): the same rule,
    // so the same weights up to float rounding.
    REQUIRE_DATA();
    auto mesh = readMeshVertexNormals(test::dataFile("bunny.ply"));
    ASSERT_TRUE(mesh.ok()) << mesh.status().message();
    std::vector<Surfel> own;
    for (size_t i = 0; i < mesh->positions.size(); ++i) {
        if (length(mesh->normals[i]) < 0.5f) continue;
        Surfel s;
        s.position = mesh->positions[i];
        s.normal = mesh->normals[i];
        own.push_back(s);
    }
    LevelNode node;
    node.surfels = own;
    LevelNode* nodes[] = {&node};
    LevelParams p;
    p.kernelScale = kDefaultKernelScale;
    p.radii = false;  // one kernel width for all: the rule has no border case
    p.threads = 2;
    computeLevelAttributes(nodes, {}, p);
    ASSERT_EQ(node.weights.size(), own.size());
    const double r = p.kernelScale * node.h, cutoff2 = 2 * p.cutoff;
    size_t checked = 0, summedMore = 0;
    for (size_t i = 0; i < own.size(); i += 17, ++checked) {
        const Vec3d n = cast<double>(own[i].normal);
        double sum = 0;
        int terms = 0;
        for (const Surfel& o : own) {
            if (dot(o.normal, own[i].normal) < 0) continue;
            Vec3d d = o.position - own[i].position;
            double along = dot(d, n);
            if (std::fabs(along) > kDefaultZt * r) continue;
            double y2 = (dot(d, d) - along * along) / (r * r);
            if (y2 <= cutoff2) sum += std::exp(-0.5 * y2), ++terms;
        }
        summedMore += terms > 1;
        EXPECT_NEAR(node.weights[i], 1.0 / std::max(sum, 1.0), 2e-5 / std::max(sum, 1.0)) << "surfel " << i;
    }
    EXPECT_GT(checked, 2000u);
    EXPECT_GT(summedMore, checked / 2) << "most weights should sum several kernels";
}
