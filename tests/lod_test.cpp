// Level-of-detail selection (client/stream/lod_selection): every drawn node is
// fine enough or a leaf, and no finer than needed (its parent was too coarse),
// no node is drawn together with an ancestor,
// replacement draws parents while children are missing, and culling never
// changes the image (surfcast-view --lod with and without --no-culling).
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <map>
#include <set>

#include "image.h"
#include "lod_selection.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace surfcast {
namespace {

using test::binary;
using test::run;
using test::TempDir;

class Lod : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = new TempDir;
        auto r = test::buildScene(dir_->file("scene"), 200000, {"--capacity", "3000"});
        ASSERT_EQ(r.exitCode, 0) << r.output;
    }
    static void TearDownTestSuite() {
        delete dir_;
        dir_ = nullptr;
    }
    static TempDir* dir_;
};
TempDir* Lod::dir_ = nullptr;

// Pixels whose colour differs between two PNGs of the same size.
size_t differingPixels(const std::string& pathA, const std::string& pathB) {
    auto a = readPng(pathA), b = readPng(pathB);
    EXPECT_TRUE(a && b);
    if (!a || !b || a->rgba.size() != b->rgba.size()) return SIZE_MAX;
    size_t n = 0;
    for (size_t i = 0; i < a->rgba.size(); i += 4)
        n += a->rgba[i] != b->rgba[i] || a->rgba[i + 1] != b->rgba[i + 1] || a->rgba[i + 2] != b->rgba[i + 2];
    return n;
}

const char* kCameras[] = {"3,-6,2,0,0,0.5,0,0,1,50", "0,0,1,5,5,0.5,0,0,1,70", "-8,-8,6,0,0,0,0,0,1,30",
                          "0,-2,0.4,0,5,0.2,0,0,1,60"};

TEST_F(Lod, DrawnNodesAreFineEnoughNoFinerAndNeverOverlap) {
    auto reader = TilesetReader::open(dir_->file("scene"));
    ASSERT_TRUE(reader) << reader.status().message();
    LodSelector lod(reader->info(), reader->nodes());
    const auto& nodes = lod.nodes();
    ASSERT_GT(reader->info().levels, 3);
    std::map<NodeKey, uint32_t> index;
    for (uint32_t i = 0; i < nodes.size(); ++i) index[nodes[i].key] = i;
    for (const char* text : kCameras) {
        auto camera = parseCamera(text);
        ASSERT_TRUE(camera);
        for (double target : {1.0, 4.0}) {
            LodParams params;
            params.targetPixels = target;
            auto selected = lod.select(*camera, 320, 240, params, [](uint32_t) { return true; });
            ASSERT_FALSE(selected.empty()) << text;
            std::set<NodeKey> drawn;
            for (const auto& s : selected) drawn.insert(nodes[s.index].key);
            // Independently: h * eta / (nearest corner depth of the box grown by 2h).
            Vec3d f = normalizeOrZero(camera->target - camera->eye);
            double eta = 240 / (2 * std::tan(0.5 * camera->fovYDegrees * M_PI / 180));
            auto projected = [&](uint32_t i) {
                Box3d b = lod.box(i);
                double g = 2 * nodes[i].spacing, nearest = HUGE_VAL;
                for (int c = 0; c < 8; ++c) {
                    Vec3d p{c & 1 ? b.max.x + g : b.min.x - g, c & 2 ? b.max.y + g : b.min.y - g,
                            c & 4 ? b.max.z + g : b.min.z - g};
                    nearest = std::fmin(nearest, dot(p - camera->eye, f));
                }
                return nearest > 0 ? nodes[i].spacing * eta / nearest : HUGE_VAL;
            };
            size_t minimal = 0;
            for (const auto& s : selected) {
                const NodeRecord& n = nodes[s.index];
                double px = projected(s.index);
                EXPECT_TRUE(px <= target * (1 + 1e-9) || n.childMask == 0)
                    << text << ": node " << n.key.name() << " projects its spacing to " << px << " px";
                for (NodeKey k = n.key; k.level > 0;) {
                    k = k.parent();
                    EXPECT_EQ(drawn.count(k), 0u) << n.key.name() << " drawn with its ancestor " << k.name();
                }
                // Minimal: no finer than needed. A node is drawn only because
                // its parent was too coarse for the target.
                if (n.key.level == 0) continue;
                double parentPx = projected(index.at(n.key.parent()));
                EXPECT_GT(parentPx, target * (1 - 1e-9))
                    << text << ": node " << n.key.name() << " is drawn though its parent already projects to "
                    << parentPx << " px";
                ++minimal;
            }
            EXPECT_GT(minimal, 0u) << text << ": only the root drawn; the minimality check saw nothing";
        }
    }
}

// A clip box culls exactly the nodes whose box misses it: with every node
// resident and no budget, the selection is the unclipped one less those.
TEST_F(Lod, ClipCullsExactlyTheNodesMissingTheBox) {
    auto reader = TilesetReader::open(dir_->file("scene"));
    ASSERT_TRUE(reader) << reader.status().message();
    LodSelector lod(reader->info(), reader->nodes());
    const Box3d clip{{-2, -3, 0}, {1.5, 2, 3}};
    size_t culledSomewhere = 0;
    for (const char* text : kCameras) {
        auto camera = parseCamera(text);
        ASSERT_TRUE(camera);
        LodParams params;
        auto all = [](uint32_t) { return true; };
        std::set<uint32_t> expected;
        for (const auto& s : lod.select(*camera, 320, 240, params, all)) {
            const Box3d b = lod.box(s.index);
            bool misses = false;
            for (int a = 0; a < 3; ++a) misses = misses || b.max[a] < clip.min[a] || b.min[a] > clip.max[a];
            if (!misses) expected.insert(s.index);
        }
        params.clip = clip;
        LodStats stats;
        std::set<uint32_t> clipped;
        for (const auto& s : lod.select(*camera, 320, 240, params, all, &stats)) clipped.insert(s.index);
        EXPECT_EQ(clipped, expected) << text;
        EXPECT_FALSE(clipped.empty()) << text;
        culledSomewhere += stats.clipCulled;
    }
    EXPECT_GT(culledSomewhere, 0u) << "the box culled nothing: the test proves nothing";
}

TEST_F(Lod, ReplacementDrawsParentsUntilChildrenAreResident) {
    auto reader = TilesetReader::open(dir_->file("scene"));
    ASSERT_TRUE(reader);
    LodSelector lod(reader->info(), reader->nodes());
    auto camera = parseCamera(kCameras[1]);
    LodParams params;
    LodStats all, partial;
    auto full = lod.select(*camera, 320, 240, params, [](uint32_t) { return true; }, &all);
    // Only levels 0-2 have arrived: nothing deeper is drawn, the parents stand in.
    auto resident = [&](uint32_t i) { return lod.nodes()[i].key.level <= 2; };
    auto early = lod.select(*camera, 320, 240, params, resident, &partial);
    int deepest = 0;
    for (const auto& s : full) deepest = std::max<int>(deepest, lod.nodes()[s.index].key.level);
    ASSERT_GT(deepest, 2) << "the view needs deeper levels";
    ASSERT_FALSE(early.empty());
    for (const auto& s : early) EXPECT_LE(lod.nodes()[s.index].key.level, 2);
    EXPECT_GT(partial.waiting, 0u);
    EXPECT_EQ(all.waiting, 0u);
}

TEST_F(Lod, BudgetsBindEvenlyAndMonotonically) {
    auto reader = TilesetReader::open(dir_->file("scene"));
    ASSERT_TRUE(reader);
    LodSelector lod(reader->info(), reader->nodes());
    const auto& nodes = lod.nodes();
    auto camera = parseCamera(kCameras[3]);  // close to the ground: many fine nodes
    ASSERT_TRUE(camera);
    auto all = [](uint32_t) { return true; };
    LodStats free;
    LodParams params;
    lod.select(*camera, 640, 480, params, all, &free);
    ASSERT_EQ(free.budgetLimited, 0u);
    size_t previousSplats = 0;
    double previousWorst = HUGE_VAL;
    // (A budget equal to the unlimited total may still bind: a partial cut can
    // hold more splats than the final one where children are culled.)
    for (double fraction : {0.3, 0.5, 0.8, 2.0}) {
        params.splatBudget = size_t(fraction * double(free.splats));
        LodStats st;
        auto drawn = lod.select(*camera, 640, 480, params, all, &st);
        size_t splats = 0;
        double worst = 0;
        for (const auto& s : drawn) {
            splats += nodes[s.index].surfelCount;
            if (nodes[s.index].childMask) worst = std::max(worst, s.projectedSpacing);
        }
        EXPECT_EQ(splats, st.splats);
        EXPECT_LE(splats, params.splatBudget) << fraction;
        if (fraction < 1) EXPECT_GT(st.budgetLimited, 0u) << fraction;
        else EXPECT_EQ(st.budgetLimited, 0u);
        // A larger budget draws more and leaves no node coarser.
        EXPECT_GE(splats, previousSplats) << fraction;
        EXPECT_LE(worst, previousWorst) << fraction;
        previousSplats = splats;
        previousWorst = worst;
    }
    EXPECT_EQ(previousSplats, free.splats);
    // Below the root's size, the root alone (nothing is no answer).
    params.splatBudget = 1;
    auto rootOnly = lod.select(*camera, 640, 480, params, all);
    ASSERT_EQ(rootOnly.size(), 1u);
    EXPECT_EQ(nodes[rootOnly[0].index].key.level, 0);

    // The memory budget bounds every node the view relies on (drawn, refined
    // through, waited for), counted in whole granules: half of what the view
    // uses without one.
    LodParams memory;
    memory.granule = 1024;
    size_t unlimited = 0;
    for (uint32_t i : free.used) unlimited += residentBytes(nodes[i].surfelCount, memory.granule);
    memory.memoryBudget = unlimited / 2;
    LodStats st;
    lod.select(*camera, 640, 480, memory, all, &st);
    size_t bytes = 0;
    for (uint32_t i : st.used) bytes += (nodes[i].surfelCount + 1023) / 1024 * 1024 * 32;
    EXPECT_LE(bytes, memory.memoryBudget);
    EXPECT_GT(st.budgetLimited, 0u);
}

TEST_F(Lod, CullingNeverChangesTheImage) {
    TempDir out;
    size_t culledSomewhere = 0;
    for (size_t c = 0; c < std::size(kCameras); ++c) {
        std::string camera = std::string("--camera=") + kCameras[c];
        auto on = run({binary("surfcast-view"), "--headless", dir_->file("scene"), camera, "--lod", "1", "--size",
                       "200x150", "--out", out.file("on.png")});
        ASSERT_EQ(on.exitCode, 0) << on.output;
        auto off = run({binary("surfcast-view"), "--headless", dir_->file("scene"), camera, "--lod", "1", "--no-culling",
                        "--size", "200x150", "--out", out.file("off.png")});
        ASSERT_EQ(off.exitCode, 0) << off.output;
        // Culled nodes are off screen, so the image is the same, except that
        // the additive sums run over a different (Morton-sorted) set in a
        // different order: float rounding can tip a pixel at the coverage
        // threshold. Measured: 1 pixel of 30000 in one of these views.
        size_t differing = differingPixels(out.file("on.png"), out.file("off.png"));
        EXPECT_LE(differing, 200u * 150 / 2000) << kCameras[c] << ": culling changed " << differing << " pixels";
        // The converged (last) redraw's counts.
        auto lines = test::jsonLines(on.output);
        ASSERT_FALSE(lines.empty()) << on.output;
        const nlohmann::json& last = lines.back();
        culledSomewhere += last["frustum_culled"].get<size_t>() + last["backface_culled"].get<size_t>() > 0;
    }
    EXPECT_GT(culledSomewhere, 0u) << "no view culled anything: the test proves nothing";
}

TEST_F(Lod, ConesCullTheFarSideOfASphere) {
    // A sphere with outward normals seen from outside: the nodes on its far
    // side face away from every point of their boxes and are skipped.
    TempDir out;
    std::string xyz;
    const int n = 40000;
    for (int i = 0; i < n; ++i) {
        double z = 1 - 2 * (i + 0.5) / n, r = std::sqrt(1 - z * z), phi = i * M_PI * (3 - std::sqrt(5.0));
        double x = r * std::cos(phi), y = r * std::sin(phi);
        char line[160];
        std::snprintf(line, sizeof(line), "%.6f %.6f %.6f %.6f %.6f %.6f\n", 10 * x, 10 * y, 10 * z, x, y, z);
        xyz += line;
    }
    test::writeFile(out.file("sphere.xyz"), xyz);
    auto b = run({binary("surfcast-build"), "-q", out.file("sphere.xyz"), "--columns", "x,y,z,nx,ny,nz", "--capacity", "800",
                  "-o", out.file("sphere")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    auto reader = TilesetReader::open(out.file("sphere"));
    ASSERT_TRUE(reader);
    LodSelector lod(reader->info(), reader->nodes());
    auto camera = parseCamera("40,0,0,0,0,0,0,0,1,40");
    LodStats stats;
    auto drawn = lod.select(*camera, 320, 240, {}, [](uint32_t) { return true; }, &stats);
    EXPECT_GT(stats.backfaceCulled, 0u);
    for (const auto& s : drawn) {
        // Nothing drawn lies wholly on the far side (x < -1).
        EXPECT_GT(lod.box(s.index).max.x, -1.0) << lod.nodes()[s.index].key.name();
    }
    std::string cam = "--camera=40,0,0,0,0,0,0,0,1,40";
    auto on = run({binary("surfcast-view"), "--headless", out.file("sphere"), cam, "--lod", "1", "--size", "200x150", "--out",
                   out.file("on.png")});
    auto off = run({binary("surfcast-view"), "--headless", out.file("sphere"), cam, "--lod", "1", "--no-culling", "--size",
                    "200x150", "--out", out.file("off.png")});
    ASSERT_EQ(on.exitCode, 0) << on.output;
    ASSERT_EQ(off.exitCode, 0) << off.output;
    size_t differing = differingPixels(out.file("on.png"), out.file("off.png"));
    EXPECT_LE(differing, 200u * 150 / 2000) << "backface culling changed " << differing << " pixels";
}

TEST_F(Lod, ConesCullNothingWhereNormalsAreNotOriented) {
    // Ground and a wall as bare XYZ: their estimated normals point away from
    // the centre (estimated-outward), the ground's down and the wall's to
    // either side, while their splats are drawn two-sided. A cone that faces
    // away from the eye says nothing about what the eye sees there, so
    // culling by cones would take visible ground and wall away (docs/
    // RENDERER.md); frustum culling alone leaves the image as it is.
    TempDir out;
    std::string xyz;
    char line[64];
    for (int i = 0; i < 200; ++i)
        for (int j = 0; j < 200; ++j) xyz += (std::snprintf(line, sizeof line, "%.2f %.2f 0\n", i * 0.05, j * 0.05), line);
    for (int i = 0; i < 80; ++i)
        for (int k = 1; k < 60; ++k) xyz += (std::snprintf(line, sizeof line, "%.2f 5 %.2f\n", 2 + i * 0.05, k * 0.05), line);
    test::writeFile(out.file("wall.xyz"), xyz);
    auto b = run({binary("surfcast-build"), "-q", out.file("wall.xyz"), "--capacity", "800", "-o", out.file("wall")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    auto reader = TilesetReader::open(out.file("wall"));
    ASSERT_TRUE(reader);
    ASSERT_EQ(reader->info().normalSource, "estimated-outward");
    for (const char* camera : {"--camera=5,-9,7,5,5,0.5,0,0,1,45", "--camera=5,19,7,5,5,0.5,0,0,1,45"}) {
        auto on = run({binary("surfcast-view"), "--headless", out.file("wall"), camera, "--lod", "1", "--size", "200x150",
                       "--out", out.file("on.png")});
        auto off = run({binary("surfcast-view"), "--headless", out.file("wall"), camera, "--lod", "1", "--no-culling",
                        "--size", "200x150", "--out", out.file("off.png")});
        ASSERT_EQ(on.exitCode, 0) << on.output;
        ASSERT_EQ(off.exitCode, 0) << off.output;
        // The bound of CullingNeverChangesTheImage: float rounding only.
        size_t differing = differingPixels(out.file("on.png"), out.file("off.png"));
        EXPECT_LE(differing, 200u * 150 / 2000) << camera << ": culling changed " << differing << " pixels";
    }
}

// The conformance case both clients' selections run (tests/conformance/
// lod_order.json, which derives its answer): nodes of equal priority are
// refined smaller key first, so that a budget cuts the same nodes in both.
TEST(LodOrder, EqualPrioritiesRefineSmallerKeyFirstAsInTheBrowser) {
    const nlohmann::json c = test::conformanceCases("lod_order.json");
    TilesetInfo info;
    info.rootMin = {c["root_min"][0].get<double>(), c["root_min"][1].get<double>(), c["root_min"][2].get<double>()};
    info.rootEdge = c["root_edge"].get<double>();
    const auto& levels = c["levels"];
    info.levels = int(levels.size());
    std::vector<NodeRecord> nodes;
    for (int level = 0; level < info.levels; ++level)
        for (uint32_t x = 0; x < (1u << level); ++x)
            for (uint32_t y = 0; y < (1u << level); ++y)
                for (uint32_t z = 0; z < (1u << level); ++z) {
                    NodeRecord r;
                    r.key = {uint8_t(level), x, y, z};
                    r.childMask = level + 1 < info.levels ? 0xff : 0;
                    r.flags = kFlagConeFull;
                    r.surfelCount = levels[size_t(level)]["surfels"].get<uint32_t>();
                    r.spacing = levels[size_t(level)]["spacing"].get<float>();
                    nodes.push_back(r);
                }
    LodSelector lod(info, nodes);
    auto camera = parseCamera(c["camera"].get<std::string>());
    ASSERT_TRUE(camera) << camera.status().message();
    LodParams params;
    params.targetPixels = c["target_pixels"].get<double>();
    params.frustumCulling = params.backfaceCulling = false;
    params.splatBudget = c["splat_budget"].get<size_t>();
    LodStats stats;
    auto drawn = lod.select(*camera, c["width"].get<int>(), c["height"].get<int>(), params, [](uint32_t) { return true; }, &stats);
    std::vector<NodeKey> keys;
    for (const auto& s : drawn) keys.push_back(lod.nodes()[s.index].key);
    std::sort(keys.begin(), keys.end());
    std::vector<std::string> names;
    for (const NodeKey& k : keys) names.push_back(k.name());
    EXPECT_EQ(names, c["drawn"].get<std::vector<std::string>>());
    EXPECT_GT(stats.budgetLimited, 0u);
}

}  // namespace
}  // namespace surfcast
