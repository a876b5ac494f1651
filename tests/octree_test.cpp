// Round trip through a built tile set: leaves keep every input point within
// the quantization step, levels shrink about 4x, cones bound normals, and h
// bounds the true nearest-neighbour distance.
#include <gtest/gtest.h>

#include <filesystem>

#include <cmath>
#include <map>

#include "inputs.h"
#include "neighbours.h"
#include "octree_builder.h"
#include "preview.h"
#include "stages.h"
#include "test_support.h"
#include "tileset_reader.h"

using namespace surfcast;

namespace {

struct Decoded {
    NodeRecord node;
    std::vector<Vec3d> positions;
    std::vector<Vec3f> normals;
};

std::vector<Decoded> decodeAll(const TilesetReader& set) {
    std::vector<Decoded> out;
    for (const NodeRecord& n : set.nodes()) {
        auto block = set.readBlock(n);
        EXPECT_TRUE(block.ok()) << block.status().message();
        if (!block.ok()) continue;
        Decoded d{n, {}, {}};
        for (size_t i = 0; i < block->size(); ++i) {
            d.positions.push_back(set.position(n, *block, i));
            d.normals.push_back({block->normals[3 * i], block->normals[3 * i + 1], block->normals[3 * i + 2]});
        }
        out.push_back(std::move(d));
    }
    return out;
}

double stepOf(const TilesetReader& set, const NodeRecord& n) {
    return nodeEdge(set.info(), n.key.level) / double((uint64_t(1) << n.positionBits) - 1);
}

BuildOptions quietOptions(const std::string& out) {
    BuildOptions o;
    o.output = out;
    o.progress = false;
    return o;
}

// The built-in scene at 300,000 points under a budget that splits it into
// several chunks: halos, chunk roots and the levels above them.
BuildOptions sceneAcrossChunks(const std::string& out) {
    BuildOptions o = quietOptions(out);
    o.inputs.defaultScene = true;
    o.inputs.scene.targetPoints = 300000;
    o.capacity = 5000;
    o.memoryBytes = kBaselineBytes + 2 * kBytesPerChunkPoint * 60000;
    return o;
}

// Every input point has a leaf surfel within half a quantization step per axis.
void expectInputsInLeaves(const TilesetReader& set, const std::vector<Decoded>& nodes, const InputOptions& inputs) {
    std::vector<Vec3f> leafPoints;
    double maxStep = 0;
    const Vec3d origin = set.info().rootMin;
    for (const auto& d : nodes) {
        if (d.node.childMask) continue;
        maxStep = std::max(maxStep, stepOf(set, d.node));
        for (const auto& p : d.positions) leafPoints.push_back(cast<float>(p - origin));
    }
    NeighbourIndex index(leafPoints, 2);
    auto stats = scanInputs(inputs, [](uint64_t) {});
    ASSERT_TRUE(stats.ok());
    EXPECT_EQ(leafPoints.size() <= stats->points, true);
    double worst = 0;
    uint64_t checked = 0;
    const std::vector<uint16_t> sourceIds(stats->sources.size(), 0);
    ASSERT_TRUE(forEachBatch(inputs, *stats, origin, sourceIds, {}, [&](std::span<Surfel> batch, std::span<const uint32_t>) {
        std::vector<Vec3f> q;
        for (const Surfel& s : batch) q.push_back(cast<float>(s.position));
        std::vector<int> idx;
        std::vector<float> d2;
        index.knn(q.data(), q.size(), 1, &idx, &d2);
        for (float d : d2) worst = std::max(worst, double(std::sqrt(d)));
        checked += q.size();
        return Status{};
    }).ok());
    EXPECT_EQ(checked, stats->points);
    // Half a step per axis, plus float rounding of the test's own coordinates.
    double floatSlack = set.info().rootEdge * 2e-7;
    EXPECT_LE(worst, 0.5 * maxStep * std::sqrt(3.0) + floatSlack) << "max leaf step " << maxStep;
}

void expectConesAndSpacing(const TilesetReader& set, const std::vector<Decoded>& nodes) {
    // Cones: every normal inside, but for its quantization: 8-bit octahedral
    // coordinates put a normal at most 0.952° (1.66e-2 rad) off, measured over
    // 10^6 random normals (bench/BENCHMARKS.md, "Block coding"), and the
    // cosine to the axis moves by at most that angle.
    for (const auto& d : nodes) {
        if (d.node.flags & kFlagConeFull) continue;
        for (const auto& n : d.normals)
            ASSERT_GE(dot(n, d.node.coneAxis), d.node.coneCosHalfAngle - 1.7e-2) << d.node.key.name();
    }
    // h >= the nearest-neighbour distance, over all surfels of each level.
    std::map<int, std::vector<const Decoded*>> levels;
    for (const auto& d : nodes) levels[d.node.key.level].push_back(&d);
    uint64_t total = 0, within = 0;
    for (auto& [level, members] : levels) {
        std::vector<Vec3f> pts;
        for (const Decoded* d : members)
            for (const auto& p : d->positions) pts.push_back(cast<float>(p - set.info().rootMin));
        NeighbourIndex index(pts, 2);
        std::vector<int> idx;
        std::vector<float> d2;
        index.knn(pts.data(), pts.size(), 2, &idx, &d2);
        size_t at = 0;
        for (const Decoded* d : members)
            for (size_t i = 0; i < d->positions.size(); ++i, ++at) {
                if (pts.size() < 2) continue;
                ++total;
                if (std::sqrt(d2[2 * at + 1]) <= d->node.spacing * (1 + 1e-5)) ++within;
            }
    }
    ASSERT_GT(total, 0u);
    EXPECT_GE(double(within) / double(total), 0.99) << within << " of " << total;
}

}  // namespace

TEST(Octree, IgeaScanRoundTrip) {
    REQUIRE_DATA();
    test::TempDir dir;
    BuildOptions o = quietOptions(dir.file("igea"));
    o.inputs.paths = {test::dataFile("igea.ply")};
    o.inputs.verticesOnly = true;
    o.capacity = 500;
    o.grid = 16;  // coarse cells, so several levels stay coarser than the scan
    auto summary = buildTileset(o);
    ASSERT_TRUE(summary.ok()) << summary.status().message();
    EXPECT_EQ(summary->inputPoints, 134345u);
    auto set = TilesetReader::open(dir.file("igea"));
    ASSERT_TRUE(set.ok()) << set.status().message();
    auto nodes = decodeAll(*set);
    expectInputsInLeaves(*set, nodes, o.inputs);
    expectConesAndSpacing(*set, nodes);

    // Levels as complete resamplings: level L is drawn by its nodes plus the
    // leaves above it. On a surface each level holds about 4x the one above,
    // as long as its cells are coarser than the scan's own sampling. A node
    // keeps at most a quarter of the surfels below it, and where its grid had
    // to be coarsened, at most one step more than that: a step from n to n'
    // cells per axis shrinks a surface's occupied cells by (n/n')², at most
    // (8/6)² = (4/3)² ≈ 1.78 for the floor(16 / 2^(j/4)) grids of G = 16 down
    // to 3 cells (16, 13, 11, 9, 8, 6, 5, 4, 3), so at most about 7.1x.
    int levels = set->info().levels;
    std::vector<uint64_t> complete(levels, 0);
    std::vector<uint64_t> fromLeaves(levels, 0);  // leaves hold the scan's own points, not a resampling
    for (const auto& d : nodes) {
        int l = d.node.key.level;
        complete[l] += d.node.surfelCount;
        if (!d.node.childMask)
            for (int below = l; below < levels; ++below) {
                fromLeaves[below] += d.node.surfelCount;
                if (below > l) complete[below] += d.node.surfelCount;
            }
    }
    const double inputSpacing = 0.0005;  // igea: 134k vertices on about 0.03 m², measured median
    int checked = 0;
    for (int l = 0; l + 1 < levels; ++l) {
        double cell = nodeEdge(set->info(), l + 1) / set->info().grid;
        // Levels where leaves (the scan's own points) are more than a fifth are
        // not a resampling (nodes keep at most a quarter of the surfels below
        // them, so leaves are a large share of each level).
        if (cell < 2 * inputSpacing || fromLeaves[l + 1] * 5 > complete[l + 1]) break;
        double ratio = double(complete[l + 1]) / double(complete[l]);
        EXPECT_GT(ratio, 3.0) << "level " << l;
        EXPECT_LT(ratio, 4 * 16.0 / 9.0) << "level " << l;
        ++checked;
    }
    EXPECT_GE(checked, 2);
}

TEST(Octree, GeoreferencedLasKeepsCentimetres) {
    REQUIRE_DATA();
    // Autzen: coordinates near 10^6 with a 0.01 scale; leaves must keep them.
    test::TempDir dir;
    BuildOptions o = quietOptions(dir.file("autzen"));
    o.inputs.paths = {test::dataFile("autzen_trim.las")};
    o.capacity = 20000;
    auto summary = buildTileset(o);
    ASSERT_TRUE(summary.ok()) << summary.status().message();
    auto set = TilesetReader::open(dir.file("autzen"));
    ASSERT_TRUE(set.ok());
    EXPECT_EQ(set->info().normalSource, "estimated-up");
    auto nodes = decodeAll(*set);
    for (const auto& d : nodes) {
        if (!d.node.childMask) {
            EXPECT_LE(stepOf(*set, d.node), 0.01) << d.node.key.name();
        }
    }
    expectInputsInLeaves(*set, nodes, o.inputs);
    expectConesAndSpacing(*set, nodes);
}

TEST(Octree, DefaultSceneAcrossChunks) {
    // A budget that forces several chunks: halos, chunk roots and upper levels.
    test::TempDir dir;
    BuildOptions o = sceneAcrossChunks(dir.file("scene"));
    o.threads = 2;
    auto summary = buildTileset(o);
    ASSERT_TRUE(summary.ok()) << summary.status().message();
    EXPECT_GT(summary->chunks, 2u);
    auto set = TilesetReader::open(dir.file("scene"));
    ASSERT_TRUE(set.ok());
    EXPECT_EQ(set->info().normalSource, "estimated-scan-origin");
    EXPECT_EQ(set->info().colorBits, 8);
    auto nodes = decodeAll(*set);
    expectInputsInLeaves(*set, nodes, o.inputs);
    expectConesAndSpacing(*set, nodes);
}

TEST(Octree, SeveralInputsMergeIntoOneSet) {
    REQUIRE_DATA();
    test::TempDir dir;
    BuildOptions o = quietOptions(dir.file("merged"));
    o.inputs.paths = {test::dataFile("bunny.ply"), test::dataFile("horse.ply")};
    o.inputs.verticesOnly = true;
    auto summary = buildTileset(o);
    ASSERT_TRUE(summary.ok()) << summary.status().message();
    EXPECT_EQ(summary->inputPoints, 35947u + 48485u);
    auto set = TilesetReader::open(dir.file("merged"));
    ASSERT_TRUE(set.ok());
    // The horse has (white) colour, the bunny none: colour is stored, the bunny's white.
    EXPECT_EQ(set->info().colorBits, 8);
    Box3d b = set->info().bounds;
    EXPECT_NEAR(b.min.x, -0.094690, 1e-6);  // bunny
    EXPECT_NEAR(b.min.y, -0.091670, 1e-6);  // horse
    auto nodes = decodeAll(*set);
    expectInputsInLeaves(*set, nodes, o.inputs);
}

TEST(Octree, SameBytesWhateverTheThreads) {
    // Several chunks, built by one thread and then by two in whatever order they
    // finish: the chunk layout and the block order do not depend on it. A second
    // build over the first replaces it in place. Under a sanitizer, half the
    // points and chunks of half the size: as many chunks, the same paths.
    test::TempDir dir;
    const uint64_t points = test::kSanitized ? 150000 : 300000, chunkPoints = test::kSanitized ? 30000 : 60000;
    for (int threads : {1, 2, 2}) {
        BuildOptions o = quietOptions(dir.file("t" + std::to_string(threads)));
        o.inputs.defaultScene = true;
        o.inputs.scene.targetPoints = points;
        o.capacity = 5000;
        o.memoryBytes = kBaselineBytes + 2 * kBytesPerChunkPoint * chunkPoints;
        o.threads = threads;
        auto summary = buildTileset(o);
        ASSERT_TRUE(summary.ok()) << summary.status().message();
        EXPECT_GT(summary->chunks, 2u);
    }
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"}) {
        std::string one = test::readFile(dir.file(std::string("t1/") + f)), two = test::readFile(dir.file(std::string("t2/") + f));
        EXPECT_FALSE(one.empty()) << f;
        EXPECT_TRUE(one == two) << f << " differs between 1 and 2 threads";
    }
    // Only the set is left beside it: no partial or old folders.
    size_t entries = 0;
    for (auto& e : std::filesystem::directory_iterator(dir.file(""))) entries += e.path().filename().string()[0] == '.';
    EXPECT_EQ(entries, 0u);
}

TEST(Octree, SameBytesWhateverTheThreadsReadingOneFileInParts) {
    // One LAS file, read by two threads in two parts cut within it
    // (readParts: record ranges) and by one thread whole: the same set, its
    // build record included (built to the same path).
    REQUIRE_DATA();
    {
        const std::string scan = "autzen_trim.las";
        test::TempDir dir;
        std::map<std::string, std::string> one;
        for (int threads : {1, 2}) {
            BuildOptions o = quietOptions(dir.file("set"));
            o.inputs.paths = {test::dataFile(scan)};
            o.capacity = 5000;
            o.memoryBytes = kBaselineBytes + 2 * kBytesPerChunkPoint * 40000;
            o.threads = threads;
            o.commandLine = {"-o", dir.file("set"), test::dataFile(scan)};
            if (threads == 2) {
                ASSERT_EQ(readParts(o), 2u);
                const InputPart first = inputPart(o.inputs, 0, 2);
                EXPECT_TRUE(first.last == 0 && first.end > 0) << "the first part ends within the file";
            }
            auto summary = buildTileset(o);
            ASSERT_TRUE(summary.ok()) << summary.status().message();
            EXPECT_GT(summary->chunks, 2u);
            for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin", "build.bin"}) {
                const std::string bytes = test::readFile(dir.file(std::string("set/") + f));
                EXPECT_FALSE(bytes.empty()) << f;
                if (threads == 1) one[f] = bytes;
                else EXPECT_TRUE(one[f] == bytes) << f << " differs between 1 and 2 threads";
            }
        }
    }
    // A preview of the LAS on two threads holds its sample once: every
    // previewStride-th of the file's 110,000 points.
    {
        test::TempDir dir;
        BuildOptions o = quietOptions(dir.file("preview"));
        o.inputs.paths = {test::dataFile("autzen_trim.las")};
        o.threads = 2;
        ASSERT_TRUE(publishPreview(o, 5000).ok());
        auto set = TilesetReader::open(dir.file("preview"));
        ASSERT_TRUE(set.ok()) << set.status().message();
        const uint64_t stride = set->info().previewStride, held = set->info().inputPoints;
        ASSERT_GT(stride, 1u);
        EXPECT_NEAR(double(held), 110000.0 / double(stride), 1.0) << "stride " << stride;
    }
    // Read as one part: a LAZ file (its decoder takes the threads), several files.
    BuildOptions o = quietOptions("unused");
    o.threads = 2;
    o.inputs.paths = {test::dataFile("lone-star.laz")};
    EXPECT_EQ(readParts(o), 1u);
    o.inputs.paths = {test::dataFile("autzen_trim.las"), test::dataFile("autzen_trim.las")};
    EXPECT_EQ(readParts(o), 1u);
}

TEST(Octree, EachNodeHoldsAtMostAQuarterOfTheSurfelsBelowIt) {
    // The rule (octree_builder.h, kLevelReduction): a resampled node holds at
    // most a quarter of its children's surfels, or one. Summed over the tree:
    // with T all surfels, L the leaves' (at most the input points N), I the
    // inner nodes' and n their number, I <= (T - root)/4 + n <= T/4 + n, so
    // T = L + I <= 4/3 (N + n). Before the rule, Megaplot's root kept 47,786
    // surfels above its leaves' 81,590 (1.59 per point), fragment 1.69. The
    // built-in scene runs across chunks: chunk roots and the levels above them.
    for (const std::string scan : {"scene", "Megaplot.laz", "fragment.pcd"}) {
        if (scan != "scene") REQUIRE_DATA();
        test::TempDir dir;
        BuildOptions o = scan == "scene" ? sceneAcrossChunks(dir.file("set")) : quietOptions(dir.file("set"));
        if (scan != "scene") o.inputs.paths = {test::dataFile(scan)};
        auto summary = buildTileset(o);
        ASSERT_TRUE(summary.ok()) << scan << ": " << summary.status().message();
        if (scan == "scene") {
            EXPECT_GT(summary->chunks, 2u);
        }
        auto set = TilesetReader::open(dir.file("set"));
        ASSERT_TRUE(set.ok()) << set.status().message();
        std::map<NodeKey, uint64_t> count;
        for (const NodeRecord& n : set->nodes()) count[n.key] = n.surfelCount;
        uint64_t total = 0, leaves = 0, inner = 0;
        for (const NodeRecord& n : set->nodes()) {
            total += n.surfelCount;
            if (!n.childMask) {
                leaves += n.surfelCount;
                continue;
            }
            ++inner;
            uint64_t below = 0;
            for (int c = 0; c < 8; ++c)
                if (n.childMask >> c & 1) below += count.at(n.key.child(c));
            EXPECT_LE(n.surfelCount, std::max<uint64_t>(1, below / 4)) << scan << " " << n.key.name() << " above " << below;
        }
        EXPECT_GT(inner, 0u) << scan;
        // The derived bound, which follows from the checks above and leaves
        // holding at most the input points (duplicates merged).
        EXPECT_LE(leaves, summary->inputPoints) << scan;
        EXPECT_LE(double(total), 4.0 / 3.0 * double(summary->inputPoints + inner)) << scan;
    }
}
