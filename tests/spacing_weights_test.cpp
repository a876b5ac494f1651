// h, per-surfel radii and analytic weights against hand-derived values on a
// square lattice (docs/ARCHITECTURE.md, "Spacing" and "Weights").
#include <gtest/gtest.h>

#include <cmath>

#include "level_attributes.h"
#include "mesh_reader.h"
#include "neighbours.h"
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
