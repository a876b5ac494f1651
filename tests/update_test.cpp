// Updates in place (preprocess/octree/update.h): `surfcast-build --add INPUT...
// --to SET` against a fresh build of all the inputs, the kept nodes' bytes,
// byte ranges and ETags (surfcast-serve before and after), the version before
// it for clients that opened it, and bad input that must leave the set as it
// was. The cases in stages and of --merge: update_test_stages.cpp.
#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <random>
#include <sstream>
#include <thread>
#include <tuple>

#include "block_codec.h"
#include "crc32.h"
#include "test_support.h"
#include "stages.h"
#include "tileset_reader.h"
#include "update_support.h"

using namespace surfcast;
using namespace surfcast::update_test;
namespace fs = std::filesystem;

namespace {

// An update's folder in `set` is gone, and every block file there is one the
// current version names.
void expectNothingLeftBehind(const std::string& set) {
    auto finished = TilesetReader::open(set);
    ASSERT_TRUE(finished) << finished.status().message();
    std::set<std::string> named;
    for (const BlocksPart& p : blocksPartsOf(finished->info())) named.insert(p.file);
    for (const auto& e : fs::directory_iterator(set)) {
        const std::string name = e.path().filename().string();
        EXPECT_NE(name.rfind(".update-", 0), 0u) << "left behind: " << e.path();
        if (validBlocksFile(name)) {
            EXPECT_TRUE(named.count(name)) << "a block file no version names: " << name;
        }
    }
}

}  // namespace

namespace {

TEST_F(UpdateTest, AddedScanEqualsAFreshBuildAndKeepsTheOtherNodes) {
    auto before = TilesetReader::open(set());
    ASSERT_TRUE(before) << before.status().message();
    const std::string blocksBefore = test::readFile(set() + "/blocks.bin");
    std::map<NodeKey, NodeRecord> recordsBefore;
    for (const NodeRecord& n : before->nodes()) recordsBefore[n.key] = n;

    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    auto all = base;
    all.insert(all.end(), added.begin(), added.end());
    all.insert(all.end(), {"-o", dir.file("fresh")});
    auto fresh = test::run(build(all));
    ASSERT_EQ(fresh.exitCode, 0) << fresh.output;

    auto after = TilesetReader::open(set());
    ASSERT_TRUE(after) << after.status().message();
    auto reference = TilesetReader::open(dir.file("fresh"));
    ASSERT_TRUE(reference) << reference.status().message();
    ASSERT_TRUE(verifyTileset(*after)) << "the updated set fails its checksums";
    EXPECT_NE(after->info().hierarchyFile, "hierarchy.bin");
    EXPECT_EQ(after->info().inputPoints, reference->info().inputPoints);
    EXPECT_TRUE(after->info().statistics == reference->info().statistics);
    EXPECT_TRUE(after->info().rootMin == reference->info().rootMin && after->info().rootEdge == reference->info().rootEdge);

    // The same leaf points: the count, positions within the quantization
    // step, attributes exact. A kept leaf holds the fresh build's bytes; a
    // rebuilt one quantizes the set's leaf again, which the fresh build
    // quantized once from the scan: |Q2(Q1 p) - Q3 p| <= s2/2 + s1/2 + s3/2,
    // at most 1.5 times the largest leaf step s of either set.
    double step = 0;
    std::vector<Point> updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(set(), &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(expected, updated, step));

    // Blocks the update kept lie where they lay, byte for byte, in a
    // blocks.bin no byte of which changed; the rest went into a file of their
    // own, named by its CRC: the next part of the blocks' space (version 3).
    EXPECT_TRUE(test::readFile(set() + "/blocks.bin") == blocksBefore) << "the update wrote to blocks.bin";
    const auto& parts = after->info().blocksParts;
    ASSERT_EQ(parts.size(), 2u);
    EXPECT_EQ(after->info().version, kPartsFormatVersion);
    EXPECT_EQ(parts[0], (BlocksPart{"blocks.bin", blocksBefore.size()}));
    const std::string added = test::readFile(set() + "/" + parts[1].file);
    EXPECT_EQ(added.size(), parts[1].bytes);
    EXPECT_EQ(parts[1].file, versionedBlocksFile(surfcast::crc32(added.data(), added.size())));
    const std::string blocksAfter = blocksBefore + added;
    size_t kept = 0, rebuilt = 0;
    for (const NodeRecord& n : after->nodes()) {
        if (n.blockOffset >= blocksBefore.size()) {
            ++rebuilt;
            continue;
        }
        ++kept;
        auto it = recordsBefore.find(n.key);
        ASSERT_NE(it, recordsBefore.end()) << n.key.name() << " points into the old blocks but was not in the set";
        EXPECT_EQ(n.blockOffset, it->second.blockOffset) << n.key.name();
        EXPECT_EQ(n.blockCrc, it->second.blockCrc) << n.key.name();
    }
    EXPECT_GT(kept, 0u) << "nothing was kept";
    EXPECT_GT(rebuilt, 0u);
    // The work was the change's: fewer bytes appended than a fresh build writes.
    EXPECT_LT(blocksAfter.size() - blocksBefore.size(), reference->info().blocksBytes);

    // The previous hierarchy stays for readers that opened it.
    EXPECT_TRUE(fs::exists(set() + "/hierarchy.bin"));
    EXPECT_TRUE(fs::exists(set() + "/" + after->info().hierarchyFile));
    EXPECT_TRUE(fs::exists(set() + "/" + buildRecordFile(after->info().hierarchyFile)));
    ASSERT_NO_FATAL_FAILURE(expectNothingLeftBehind(set()));
}

// A set coded as before draco-columns ("draco") with other normal bits than
// today's default keeps its coding through an update, though its build
// record names neither (as the records of builds before draco-columns).
TEST_F(UpdateTest, ASetCodedAsBeforeKeepsItsCoding) {
    const std::string old = dir.file("sets/old");
    auto args = base;
    args.insert(args.end(), {"--codec", "draco", "--normal-bits", "10", "-o", old});
    auto built = test::run(build(args));
    ASSERT_EQ(built.exitCode, 0) << built.output;
    // The record as such a build wrote it: without the two options.
    const std::string record = old + "/" + buildRecordFile("hierarchy.bin");
    std::vector<std::string> stored, before;
    auto plan = readPlan(record, &stored, true);
    ASSERT_TRUE(plan) << plan.status().message();
    for (size_t i = 0; i < stored.size(); ++i) {
        if (stored[i] == "--codec" || stored[i] == "--normal-bits") ++i;
        else before.push_back(stored[i]);
    }
    ASSERT_EQ(before.size() + 4, stored.size());
    ASSERT_TRUE(writePlan(record, *plan, before).ok());
    std::set<uint32_t> crcsBefore;
    auto previous = TilesetReader::open(old);
    ASSERT_TRUE(previous) << previous.status().message();
    for (const NodeRecord& n : previous->nodes()) crcsBefore.insert(n.blockCrc);
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", old});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    auto reader = TilesetReader::open(old);
    ASSERT_TRUE(reader) << reader.status().message();
    EXPECT_EQ(reader->info().blockCodec, BlockCodec::Draco);
    ASSERT_NE(reader->info().attribute("normal"), nullptr);
    EXPECT_EQ(reader->info().attribute("normal")->quantizationBits, 10);
    uint64_t surfels = 0;
    Status decoded = reader->forEachBlock(reader->nodes(), true, [&](const NodeRecord&, BlockData& b) {
        surfels += b.size();
        return Status{};
    });
    ASSERT_TRUE(decoded.ok()) << decoded.message();
    EXPECT_EQ(surfels, reader->info().surfels);
    // Some blocks were written anew (the added scan's), in the set's coding.
    size_t rewritten = 0;
    for (const NodeRecord& n : reader->nodes()) rewritten += !crcsBefore.count(n.blockCrc);
    EXPECT_GT(rewritten, 0u);
}

// Every node the change cannot reach keeps its block where and what it was,
// though the chunk that holds it is built again from decoded points (whose
// values, computed again, differ in rounding: isolated surfels' radii
// flipped in about 1 % of surfels, rewriting far nodes). Reach, from what a
// build looks at (docs/ARCHITECTURE.md, "Updates in place"): a chunk's halo,
// at most one counting cell (root edge / 128), and two node edges of the
// node's level (the neighbouring nodes whose h its weights take); a node
// whose box widened by the larger misses the added scan's bounds (its LAS
// header's) is one the change cannot reach.
TEST_F(UpdateTest, NodesTheChangeCannotReachKeepTheirBlocks) {
    auto before = TilesetReader::open(set());
    ASSERT_TRUE(before) << before.status().message();
    std::map<NodeKey, NodeRecord> recordsBefore;
    for (const NodeRecord& n : before->nodes()) recordsBefore[n.key] = n;
    const std::string oneThread = dir.file("one-thread"), staged = dir.file("staged");
    fs::copy(set(), oneThread, fs::copy_options::recursive);
    fs::copy(set(), staged, fs::copy_options::recursive);
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    // The rule holds in stages and on one thread too, to the same bytes
    // (the set's blocks decoded on several threads, kept nodes never
    // encoded); only the build records differ, in the command line they
    // keep (--threads 1; another folder).
    const auto files = folderFiles(set());
    auto single = test::run({test::binary("surfcast-build"), "-q", "--threads", "1", "--add", added[0], "--to", oneThread});
    ASSERT_EQ(single.exitCode, 0) << single.output;
    auto withoutRecords = [](std::map<std::string, std::string> f) {
        std::erase_if(f, [](const auto& e) { return e.first.rfind("build", 0) == 0; });
        return f;
    };
    EXPECT_TRUE(withoutRecords(folderFiles(oneThread)) == withoutRecords(files)) << "the update on one thread wrote other bytes";
    ASSERT_NO_FATAL_FAILURE(stagedUpdate(staged, dir.file("work"), {"--add", added[0]}));
    EXPECT_TRUE(withoutRecords(folderFiles(staged)) == withoutRecords(files)) << "the update in stages wrote other bytes";
    auto after = TilesetReader::open(set());
    ASSERT_TRUE(after) << after.status().message();

    // LAS header: max x, min x, max y, min y, max z, min z at byte 179.
    const std::string header = test::readFile(added[0]).substr(0, 227);
    ASSERT_EQ(header.size(), 227u);
    double bounds[6];
    std::memcpy(bounds, header.data() + 179, sizeof bounds);
    const TilesetInfo& info = after->info();
    size_t far = 0, rewritten = 0;
    std::string which;
    for (const NodeRecord& n : after->nodes()) {
        const double edge = nodeEdge(info, n.key.level);
        const double reach = std::max(info.rootEdge / 128, 2 * edge);
        const Vec3d lo = nodeMin(info, n.key);
        bool misses = false;
        for (int a = 0; a < 3; ++a)
            misses = misses || lo[a] - reach > bounds[2 * a] || lo[a] + edge + reach < bounds[2 * a + 1];
        auto was = recordsBefore.find(n.key);
        if (!misses || was == recordsBefore.end()) continue;
        ++far;
        if (n.blockOffset != was->second.blockOffset || n.blockCrc != was->second.blockCrc) {
            ++rewritten;
            if (which.size() < 200) which += " " + n.key.name();
        }
    }
    EXPECT_GT(far, 20u) << "the case needs nodes far from the change";
    EXPECT_EQ(rewritten, 0u) << "of " << far << " nodes the change cannot reach, rewritten:" << which;
}

// A scan whose points repeat the set's exactly (one file added twice,
// overlapping flight lines with the same returns): a fresh build merges each
// pair, keeping the lower input's, and so must the update, whose set points
// are decoded from their leaves while the added ones are read raw (keeping
// both would give 114,212 leaf points where the fresh build has 110,000).
// Beside it, the same scan moved by 0.4 of its coordinates' step: on another
// lattice, so no point repeats one of the set's, though most quantize to a
// position of one (which the update must not take for a repeat).
TEST_F(UpdateTest, AnAddedCopyOfTheSetsScanMergesAsInAFreshBuild) {
    const std::string copy = dir.file("again.laz"), moved = dir.file("moved.laz");
    fs::copy_file(base[3], copy);
    const char* script =
        "import laspy, sys\n"
        "f = laspy.read(sys.argv[1])\n"
        "f.header.offsets = f.header.offsets + 0.4 * f.header.scales\n"
        "f.write(sys.argv[2])\n"
        "print(len(f.points))\n";
    auto written = test::run({SURFCAST_TEST_PYTHON, "-c", script, base[3], moved});
    ASSERT_EQ(written.exitCode, 0) << written.output;
    const size_t movedPoints = std::stoul(written.output.substr(written.output.find_last_of('\n', written.output.size() - 2) + 1));
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", copy, moved, "--to", set()});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    auto all = base;
    all.insert(all.end(), {copy, moved, "-o", dir.file("fresh")});
    auto fresh = test::run(build(all));
    ASSERT_EQ(fresh.exitCode, 0) << fresh.output;

    // As AddedScanEqualsAFreshBuildAndKeepsTheOtherNodes: every point within
    // 1.5 leaf steps, attributes and input exact; the set before holds each
    // of the copy's points already, and none of the moved scan's.
    double step = 0;
    std::vector<Point> before, updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(shared(), &step, &before));
    ASSERT_NO_FATAL_FAILURE(leafPoints(set(), &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    EXPECT_EQ(expected.size(), before.size() + movedPoints);
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(expected, updated, step));
}

// Where the set stores intensity in steps wider than 1 (a range past 4,096
// values), a set point decodes to its step's value, not its own. Of it and
// an added repeat, the set's input must stay all the same, as in a fresh
// build (docs/FORMAT.md: the lowest stored intensity, then input), or removing
// the repeat again would take the set's point with it.
TEST_F(UpdateTest, RemovingARepeatOfTheSetsScanGivesBackTheSet) {
    const std::string wide = dir.file("wide.laz"), again = dir.file("again.laz");
    const char* script =
        "import laspy, sys, numpy as np\n"
        "f = laspy.read(sys.argv[1])\n"
        "f.intensity = np.minimum(f.intensity.astype(np.int64) * 97 + np.arange(len(f.points)) % 89, 65535).astype(np.uint16)\n"
        "f.write(sys.argv[2])\n"
        "f.write(sys.argv[3])\n";
    auto written = test::run({SURFCAST_TEST_PYTHON, "-c", script, base[3], wide, again});
    ASSERT_EQ(written.exitCode, 0) << written.output;
    auto built = test::run(build({wide, base[4], "-o", dir.file("wide-set")}));
    ASSERT_EQ(built.exitCode, 0) << built.output;
    fs::copy(dir.file("wide-set"), dir.file("before"), fs::copy_options::recursive);
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", again, "--to", dir.file("wide-set")});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    update = test::run({test::binary("surfcast-build"), "-q", "--remove", "again.laz", "--to", dir.file("wide-set")});
    ASSERT_EQ(update.exitCode, 0) << update.output;

    auto reader = TilesetReader::open(dir.file("before"));
    ASSERT_TRUE(reader) << reader.status().message();
    const AttributeInfo* intensity = reader->info().attribute("intensity");
    ASSERT_NE(intensity, nullptr);
    ASSERT_GT(intensity->scale, 1) << "the case needs intensity steps wider than 1";
    double step = 0;
    std::vector<Point> before, after;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("before"), &step, &before));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("wide-set"), &step, &after));
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(before, after, step));
}

// An input of float coordinates has no lattice to take the set's quantized
// points back to, so the update snaps the added points onto the set's leaves
// instead (update.cpp, SetLeaves): a copy of the scan merges all the same.
TEST_F(UpdateTest, AnAddedCopyOfAFloatScanMergesAsInAFreshBuild) {
    const std::string scan = test::dataFile("fragment.pcd"), copy = dir.file("again.pcd");
    fs::copy_file(scan, copy);
    auto built = test::run(build({scan, "-o", dir.file("scan")}));
    ASSERT_EQ(built.exitCode, 0) << built.output;
    fs::copy(dir.file("scan"), dir.file("before"), fs::copy_options::recursive);
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", copy, "--to", dir.file("scan")});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    auto fresh = test::run(build({scan, copy, "-o", dir.file("fresh")}));
    ASSERT_EQ(fresh.exitCode, 0) << fresh.output;

    double step = 0;
    std::vector<Point> before, updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("scan"), &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("before"), &step, &before));
    EXPECT_EQ(expected.size(), before.size()) << "the fresh build keeps the copy's points apart";
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(expected, updated, step));
}

// Added points that repeat none of the set's keep their positions: two of
// them closer than the leaf's step, 3.3 steps from a point of the set, stay
// two, as in a fresh build (snapping every added point onto the leaf's grid
// would make the two one).
TEST_F(UpdateTest, AddedPointsOnNoneOfTheSetsPositionsKeepTheirOwn) {
    const std::string scan = test::dataFile("fragment.pcd"), pairs = dir.file("pairs.xyz");
    auto built = test::run(build({scan, "-o", dir.file("scan")}));
    ASSERT_EQ(built.exitCode, 0) << built.output;
    double step = 0;
    std::vector<Point> before;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("scan"), &step, &before));
    ASSERT_GT(step, 0);
    {
        std::ofstream out(pairs);
        out.precision(12);
        for (size_t i = 0; i < before.size(); i += 97)
            for (double k : {3.3, 3.5}) {
                const Vec3d p = before[i].p + Vec3d{1, 1, 1} * (k * step);
                out << p.x << ' ' << p.y << ' ' << p.z << '\n';
            }
        ASSERT_TRUE(out.good());
    }
    const size_t added = 2 * ((before.size() + 96) / 97);
    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", pairs, "--to", dir.file("scan")});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    auto fresh = test::run(build({scan, pairs, "-o", dir.file("fresh")}));
    ASSERT_EQ(fresh.exitCode, 0) << fresh.output;

    std::vector<Point> updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("scan"), &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    EXPECT_EQ(expected.size(), before.size() + added);
    EXPECT_EQ(updated.size(), before.size() + added);
}

// --replace of a float scan: the added points are not moved onto the
// removed scan's points, so two of them within a tenth and three tenths of a
// leaf step of a removed point stay two, as in a fresh build without it.
TEST_F(UpdateTest, ReplacedFloatScanLeavesNoPointOnTheRemovedOnes) {
    const std::string scan = test::dataFile("fragment.pcd"), other = test::dataFile("milk_cartoon_all_small_clorox.pcd");
    const std::string pairs = dir.file("pairs.xyz");
    auto built = test::run(build({scan, other, "-o", dir.file("set")}));
    ASSERT_EQ(built.exitCode, 0) << built.output;
    double step = 0;
    std::vector<Point> before;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("set"), &step, &before));
    size_t written = 0;
    {
        std::ofstream out(pairs);
        out.precision(12);
        for (size_t i = 0; i < before.size(); i += 97)
            if (before[i].input == 0)
                for (double k : {0.1, 0.3}) {
                    const Vec3d p = before[i].p + Vec3d{1, 1, 1} * (k * step);
                    out << p.x << ' ' << p.y << ' ' << p.z << '\n';
                    ++written;
                }
        ASSERT_TRUE(out.good());
    }
    ASSERT_GT(written, 0u);
    auto update = test::run({test::binary("surfcast-build"), "-q", "--replace", "fragment.pcd", pairs, "--to", dir.file("set")});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    auto fresh = test::run(build({other, pairs, "-o", dir.file("fresh")}));
    ASSERT_EQ(fresh.exitCode, 0) << fresh.output;

    size_t others = 0;
    for (const Point& p : before) others += p.input == 1;
    std::vector<Point> updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("set"), &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    EXPECT_EQ(expected.size(), others + written);
    EXPECT_EQ(updated.size(), others + written);
}

// Images at --lod 1 from four views around the set, 640 x 360, within mean
// FLIP 0.01 of the fresh build's (the bound for updates in place; the
// benchmark's 104 M-point update measured 0.0019-0.0024: bench/BENCHMARKS.md,
// "Updates in place").
TEST_F(UpdateTest, ImagesAtLod1MatchAFreshBuild) {
    auto r = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto all = base;
    all.insert(all.end(), added.begin(), added.end());
    all.insert(all.end(), {"-o", dir.file("fresh")});
    ASSERT_EQ(test::run(build(all)).exitCode, 0);
    auto fresh = TilesetReader::open(dir.file("fresh"));
    ASSERT_TRUE(fresh);
    const Box3d& b = fresh->info().bounds;
    const Vec3d centre = (b.min + b.max) * 0.5, size = b.max - b.min;
    const double radius = std::max({size.x, size.y, size.z});
    const int around[4][2] = {{1, 0}, {0, 1}, {-1, 0}, {0, -1}};
    for (int v = 0; v < 4; ++v) {
        const Vec3d eye = centre + Vec3d{around[v][0] * radius, around[v][1] * radius, 0.6 * radius};
        std::ostringstream camera;
        camera.precision(17);
        camera << "--camera=" << eye.x << ',' << eye.y << ',' << eye.z << ',' << centre.x << ',' << centre.y << ',' << centre.z
               << ",0,0,1,45";
        std::string images[2];
        for (int k = 0; k < 2; ++k) {
            images[k] = dir.file("view" + std::to_string(v) + (k ? "-updated.png" : "-fresh.png"));
            auto view = test::run({test::binary("surfcast-view"), "--headless", k ? set() : dir.file("fresh"), "--size", "640x360", "--lod",
                                   "1", camera.str(), "--out", images[k]});
            ASSERT_EQ(view.exitCode, 0) << view.output;
            // (A view of little of the set would pass any bound: each covers over a tenth of the frame.)
            const auto frames = test::jsonLines(view.output);
            ASSERT_FALSE(frames.empty()) << view.output;
            EXPECT_GT(frames.back()["pixels_covered"].get<double>(), 0.1 * 640 * 360) << "view " << v;
        }
        auto flip = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/flip_mean.py", images[0], images[1]});
        ASSERT_EQ(flip.exitCode, 0) << flip.output;
        const double mean = std::stod(flip.output);
        EXPECT_LT(mean, 0.01) << "view " << v;
    }
}

// Provenance: each leaf point's input attribute names the file it came
// from (the files' own point counts, read by laspy), and --remove of the
// added scan gives back the set before it: the same leaf points, within the
// quantization step (1.5 steps: see above).
TEST_F(UpdateTest, RemovingTheAddedScanGivesBackTheSetBefore) {
    double step = 0;
    std::vector<Point> original;
    ASSERT_NO_FATAL_FAILURE(leafPoints(set(), &step, &original));
    auto r = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;

    auto withAdded = TilesetReader::open(set());
    ASSERT_TRUE(withAdded) << withAdded.status().message();
    const std::vector<std::string>& names = withAdded->info().inputs;
    ASSERT_EQ(names.size(), 16u);
    ASSERT_NE(withAdded->info().attribute("input"), nullptr);
    EXPECT_EQ(withAdded->info().attribute("input")->type, "uint8");
    std::vector<Point> points;
    ASSERT_NO_FATAL_FAILURE(leafPoints(set(), &step, &points));
    std::map<std::string, uint64_t> perInput;
    for (const Point& p : points) {
        ASSERT_GE(p.input, 0);
        ASSERT_LT(size_t(p.input), names.size());
        perInput[names[size_t(p.input)]]++;
    }
    std::string script = "import laspy, sys\nfor f in sys.argv[1:]: print(f.rsplit('/', 1)[1], laspy.open(f).header.point_count)\n";
    std::vector<std::string> args = {SURFCAST_TEST_PYTHON, "-c", script};
    args.insert(args.end(), base.begin(), base.end());
    args.insert(args.end(), added.begin(), added.end());
    auto counts = test::run(args);
    ASSERT_EQ(counts.exitCode, 0) << counts.output;
    std::istringstream lines(counts.output);
    std::string name;
    uint64_t n = 0;
    size_t files = 0;
    while (lines >> name >> n) {
        EXPECT_EQ(perInput[name], n) << name;
        ++files;
    }
    EXPECT_EQ(files, 16u);

    r = test::run({test::binary("surfcast-build"), "-q", "--remove", fs::path(added[0]).filename().string(), "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::vector<Point> removed;
    ASSERT_NO_FATAL_FAILURE(leafPoints(set(), &step, &removed));
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(original, removed, step));
    // Removed twice, or never there.
    r = test::run({test::binary("surfcast-build"), "-q", "--remove", added[0], "--to", set()});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("no points"), std::string::npos) << r.output;
    r = test::run({test::binary("surfcast-build"), "-q", "--remove", "nothing.laz", "--to", set()});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("not one of the set's inputs"), std::string::npos) << r.output;

    // --compact: the same nodes and bytes, none of the replaced ones.
    auto updated = TilesetReader::open(set());
    ASSERT_TRUE(updated) << updated.status().message();
    std::map<NodeKey, std::pair<uint32_t, uint32_t>> blocks;
    uint64_t live = 0;
    for (const NodeRecord& n : updated->nodes()) blocks[n.key] = {n.blockCrc, n.blockSize}, live += n.blockSize;
    ASSERT_GT(updated->info().blocksBytes, live) << "two updates left no replaced blocks to reclaim";
    ASSERT_EQ(updated->info().blocksParts.size(), 3u) << "each update adds a block file";
    r = test::run({test::binary("surfcast-build"), "--compact", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto compacted = TilesetReader::open(set());
    ASSERT_TRUE(compacted) << compacted.status().message();
    EXPECT_TRUE(verifyTileset(*compacted));
    EXPECT_EQ(fs::file_size(set() + "/blocks.bin"), live);
    EXPECT_EQ(compacted->info().hierarchyFile, "hierarchy.bin");
    std::map<NodeKey, std::pair<uint32_t, uint32_t>> after;
    for (const NodeRecord& n : compacted->nodes()) after[n.key] = {n.blockCrc, n.blockSize};
    EXPECT_TRUE(after == blocks) << "compaction changed a node's bytes";
    EXPECT_TRUE(fs::exists(set() + "/build.bin"));
    for (const auto& e : fs::directory_iterator(set())) {
        const std::string name = e.path().filename().string();
        EXPECT_TRUE(name == "tileset.json" || name == "hierarchy.bin" || name == "blocks.bin" || name == "build.bin") << name;
    }
}

// A set of one input stores no provenance (docs/FORMAT.md): adding a second
// input builds every node again with the attribute, to the leaf points of a
// fresh build of both (1.5 steps: see above), and keeps the old blocks for
// readers that opened the set before; --remove of the added input then gives
// back the first input's points, each of input 0. The scan's west half (7
// chunks) takes its east half, which grows its root (by two levels: the
// halves' width is just over the half's root edge).
TEST_F(UpdateTest, ASetOfOneInputTakesASecond) {
    auto r = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/split_laz.py", test::dataFile("autzen_trim.las"), dir.file("halves"),
                        "--cells", "2x1x1", "--min-files", "2"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const std::string west = dir.file("halves/r000000.laz"), east = dir.file("halves/r000001.laz");
    const std::string one = dir.file("sets/one");
    r = test::run(build({west, "-o", one}));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    double step = 0;
    std::vector<Point> original;
    ASSERT_NO_FATAL_FAILURE(leafPoints(one, &step, &original));
    ASSERT_FALSE(original.empty());
    ASSERT_EQ(original[0].input, -1) << "a set of one input stores its points' input";
    const std::string blocksBefore = test::readFile(one + "/blocks.bin");

    fs::copy(one, dir.file("one-before"), fs::copy_options::recursive);
    r = test::run({test::binary("surfcast-build"), "-q", "--add", east, "--to", one});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    // In stages, the same bytes (every chunk built again, provenance gained).
    const auto oneProcess = folderFiles(one);
    fs::remove_all(one);
    fs::copy(dir.file("one-before"), one, fs::copy_options::recursive);
    ASSERT_NO_FATAL_FAILURE(stagedUpdate(one, dir.file("work"), {"--add", east}));
    EXPECT_TRUE(folderFiles(one) == oneProcess) << "the update in stages wrote other bytes than in one process";
    auto after = TilesetReader::open(one);
    ASSERT_TRUE(after) << after.status().message();
    ASSERT_TRUE(verifyTileset(*after));
    ASSERT_NE(after->info().attribute("input"), nullptr);
    EXPECT_EQ(after->info().inputs, (std::vector<std::string>{"r000000.laz", "r000001.laz"}));
    const std::string blocksAfter = test::readFile(one + "/blocks.bin");
    EXPECT_TRUE(blocksAfter.compare(0, blocksBefore.size(), blocksBefore) == 0) << "the update rewrote bytes of blocks.bin";
    for (const NodeRecord& n : after->nodes()) EXPECT_GE(n.blockOffset, blocksBefore.size()) << n.key.name() << " kept a block without provenance";

    r = test::run(build({west, east, "-o", dir.file("fresh")}));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::vector<Point> updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(one, &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(expected, updated, step));

    r = test::run({test::binary("surfcast-build"), "-q", "--remove", "r000001.laz", "--to", one});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    // A set of one input has no input to remove: refused, before anything is read.
    const std::string west2 = dir.file("sets/west");
    r = test::run(build({west, "-o", west2}));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const std::string tilesetBefore = test::readFile(west2 + "/tileset.json");
    r = test::run({test::binary("surfcast-build"), "-q", "--replace", "r000000.laz", east, "--to", west2});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("a set of one input"), std::string::npos) << r.output;
    EXPECT_EQ(test::readFile(west2 + "/tileset.json"), tilesetBefore);
    std::vector<Point> removed;
    ASSERT_NO_FATAL_FAILURE(leafPoints(one, &step, &removed));
    for (Point& p : original) p.input = 0;
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(original, removed, step));
}

// --replace OLD NEW equals a fresh build of the inputs without OLD and with NEW.
TEST_F(UpdateTest, ReplacedScanEqualsAFreshBuild) {
    const std::string old = base[6];
    auto r = test::run({test::binary("surfcast-build"), "-q", "--replace", old, added[0], "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::vector<std::string> inputs;
    for (const std::string& b : base)
        if (b != old) inputs.push_back(b);
    inputs.insert(inputs.end(), {added[0], "-o", dir.file("fresh")});
    auto fresh = test::run(build(inputs));
    ASSERT_EQ(fresh.exitCode, 0) << fresh.output;
    double step = 0;
    std::vector<Point> updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(set(), &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    for (auto* points : {&updated, &expected})
        for (Point& p : *points) p.input = -1;  // the two number their inputs differently
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(expected, updated, step));
}

// Every leaf point survives an update on a scan whose points lie on the
// faces of the nodes' boxes once quantized: the lion (4 x 4 cells, one added
// to the other 15) lost 79 of 341,989 points before update.cpp held such a
// point inside its node, as a kept neighbouring chunk dropped it. Its
// intensities span 0-65535, stored in steps of 16: the top step read back
// as 65,536 wrapped to 0 in 44 points before update.cpp clamped it.
TEST_F(UpdateTest, PointsOnTheNodesFacesStayInTheirChunk) {
    auto split = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/split_laz.py", test::dataFile("lion_takanawa.copc.laz"),
                            dir.file("lion"), "--cells", "4x4x1", "--min-files", "16"});
    ASSERT_EQ(split.exitCode, 0) << split.output;
    std::vector<std::string> cells, all;
    for (int i = 0; i < 16; ++i) {
        char name[32];
        std::snprintf(name, sizeof name, "/lion/r%06d.laz", i);
        if (i != 5) cells.push_back(dir.path() + name);
    }
    const std::string cell = dir.path() + "/lion/r000005.laz";
    all = cells;
    all.insert(all.end(), {cell, "-o", dir.file("lion-fresh")});
    cells.insert(cells.end(), {"-o", dir.file("lion-set")});
    for (auto* args : {&cells, &all}) {
        args->insert(args->begin(), {test::binary("surfcast-build"), "-q", "--memory", "100M", "--capacity", "2000"});
        auto r = test::run(*args);
        ASSERT_EQ(r.exitCode, 0) << r.output;
    }
    // The set's own leaf steps count too: they quantized the points first.
    double step = 0;
    std::vector<Point> updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("lion-set"), &step, &updated));
    updated.clear();
    auto r = test::run({test::binary("surfcast-build"), "-q", "--add", cell, "--to", dir.file("lion-set")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("lion-set"), &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("lion-fresh"), &step, &expected));
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(expected, updated, step));
}

// A scan beyond the set's root cube grows the root: the old root becomes a
// node of a cube of 2^d of its edges, so every kept node decodes, under its
// new key, to the very points it held; the set equals a fresh build of all
// the inputs in its leaf points.
TEST_F(UpdateTest, GrowingPastTheRootKeepsTheOriginalNodesPoints) {
    // The south-west quarter of the scan (cells 0, 1, 4, 5), then the far
    // north-east cell: beyond the quarter's root cube.
    const std::string quarter = dir.file("sets/q"), far = dir.path() + "/parts/r000015.laz";
    std::vector<std::string> cells;
    for (const char* c : {"r000000", "r000001", "r000004", "r000005"}) cells.push_back(dir.path() + "/parts/" + c + ".laz");
    auto args = cells;
    args.insert(args.end(), {"-o", quarter});
    auto r = test::run(build(args));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    fs::copy(quarter, dir.file("quarter-before"), fs::copy_options::recursive);
    auto before = TilesetReader::open(dir.file("quarter-before"));
    ASSERT_TRUE(before) << before.status().message();
    r = test::run({test::binary("surfcast-build"), "-q", "--add", far, "--to", quarter});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto after = TilesetReader::open(quarter);
    ASSERT_TRUE(after) << after.status().message();
    ASSERT_TRUE(verifyTileset(*after));

    // The new root: 2^d old edges, the old root at whole edges from its corner.
    const TilesetInfo &a = before->info(), &b = after->info();
    const double ratio = b.rootEdge / a.rootEdge;
    const int d = int(std::lround(std::log2(ratio)));
    ASSERT_GE(d, 1);
    ASSERT_EQ(std::ldexp(1.0, d), ratio);
    uint32_t offset[3];
    for (int axis = 0; axis < 3; ++axis) {
        const double o = (a.rootMin[axis] - b.rootMin[axis]) / a.rootEdge;
        ASSERT_EQ(o, std::round(o)) << "the old root is not aligned in the new one";
        offset[axis] = uint32_t(o);
    }
    std::map<NodeKey, NodeRecord> oldNodes;
    for (const NodeRecord& n : before->nodes()) {
        NodeKey k = n.key;
        k.level = uint8_t(n.key.level + d);
        k.x += offset[0] << n.key.level, k.y += offset[1] << n.key.level, k.z += offset[2] << n.key.level;
        oldNodes[k] = n;
    }
    size_t kept = 0;
    for (const NodeRecord& n : after->nodes()) {
        if (n.blockOffset >= a.blocksBytes) continue;
        auto it = oldNodes.find(n.key);
        ASSERT_NE(it, oldNodes.end()) << n.key.name() << ": kept, but no old node has this key once moved";
        ASSERT_EQ(n.blockCrc, it->second.blockCrc) << n.key.name();
        auto was = before->readBlock(it->second);
        auto is = after->readBlock(n);
        ASSERT_TRUE(was && is);
        for (size_t i = 0; i < is->size(); ++i) {
            const Vec3d p = after->position(n, *is, i), q = before->position(it->second, *was, i);
            ASSERT_NEAR(p.x, q.x, 1e-9 * b.rootEdge) << n.key.name();
            ASSERT_NEAR(p.y, q.y, 1e-9 * b.rootEdge) << n.key.name();
            ASSERT_NEAR(p.z, q.z, 1e-9 * b.rootEdge) << n.key.name();
        }
        ++kept;
    }
    EXPECT_GT(kept, 0u) << "growing the root kept no node";

    // In stages, the same bytes: update.bin's growth gives the root again.
    const auto oneProcess = folderFiles(quarter);
    fs::remove_all(quarter);
    fs::copy(dir.file("quarter-before"), quarter, fs::copy_options::recursive);
    ASSERT_NO_FATAL_FAILURE(stagedUpdate(quarter, dir.file("work"), {"--add", far}));
    EXPECT_TRUE(folderFiles(quarter) == oneProcess) << "the update in stages wrote other bytes than in one process";

    cells.insert(cells.end(), {far, "-o", dir.file("fresh")});
    auto fresh = test::run(build(cells));
    ASSERT_EQ(fresh.exitCode, 0) << fresh.output;
    double step = 0;
    std::vector<Point> updated, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(quarter, &step, &updated));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(expected, updated, step));

    // A second update after the first grew the root (the record's statistics
    // now derive another root than the set's): the far cell removed again
    // gives back the quarter's points.
    r = test::run({test::binary("surfcast-build"), "-q", "--remove", far, "--to", quarter});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::vector<Point> again, original;
    ASSERT_NO_FATAL_FAILURE(leafPoints(quarter, &step, &again));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("quarter-before"), &step, &original));
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(original, again, step));
}

// surfcast-serve across an update: nodes whose blocks did not change keep
// their ETags (304 to a client's conditional request), and a client that read
// tileset.json before the switch still gets its version's nodes, batches and
// hierarchy.
TEST_F(UpdateTest, ServedNodesKeepTheirETagsAndTheVersionBeforeStaysReadable) {
    auto before = TilesetReader::open(set());
    ASSERT_TRUE(before) << before.status().message();
    const std::string oldVersion = std::to_string(before->info().hierarchyCrc);
    const std::string oldHierarchy = test::readFile(set() + "/hierarchy.bin");
    test::Child server = test::spawn({test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0"});
    ASSERT_TRUE(server.waitFor("(1 tile sets)\n")) << server.log;
    const size_t at = server.log.find("http://127.0.0.1:");
    ASSERT_NE(at, std::string::npos) << server.log;
    httplib::Client c("127.0.0.1", std::atoi(server.log.c_str() + at + 17));
    std::map<NodeKey, NodeRecord> oldRecords;
    std::map<NodeKey, std::string> etags, bodies;
    for (const NodeRecord& n : before->nodes()) {
        auto r = c.Get("/sets/s/nodes/" + n.key.name());
        ASSERT_TRUE(r && r->status == 200) << n.key.name();
        oldRecords[n.key] = n;
        etags[n.key] = r->get_header_value("ETag");
        bodies[n.key] = r->body;
    }

    auto update = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    ASSERT_EQ(update.exitCode, 0) << update.output;
    auto after = TilesetReader::open(set());
    ASSERT_TRUE(after) << after.status().message();
    auto json = c.Get("/sets/s/tileset.json");
    ASSERT_TRUE(json && json->status == 200);
    EXPECT_EQ(json->body, test::readFile(set() + "/tileset.json")) << "the server still serves the old version";

    size_t same = 0, changed = 0;
    std::vector<NodeKey> rebuilt;  // in both versions, with other bytes
    for (const NodeRecord& n : after->nodes()) {
        auto old = oldRecords.find(n.key);
        const bool unchanged = old != oldRecords.end() && old->second.blockCrc == n.blockCrc && old->second.blockSize == n.blockSize;
        httplib::Headers conditional;
        if (old != oldRecords.end()) conditional.insert({"If-None-Match", etags[n.key]});
        auto r = c.Get("/sets/s/nodes/" + n.key.name(), conditional);
        ASSERT_TRUE(r) << n.key.name();
        EXPECT_EQ(r->status, unchanged ? 304 : 200) << n.key.name();
        (unchanged ? same : changed)++;
        if (!unchanged && old != oldRecords.end()) rebuilt.push_back(n.key);
    }
    EXPECT_GT(same, 0u);
    EXPECT_GT(changed, 0u);
    ASSERT_FALSE(rebuilt.empty());

    // The version before: its nodes by key, in a batch, and its hierarchy file.
    for (const NodeKey& key : rebuilt) {
        auto r = c.Get("/sets/s/nodes/" + key.name() + "?v=" + oldVersion);
        ASSERT_TRUE(r && r->status == 200) << key.name();
        EXPECT_EQ(r->body, bodies[key]) << key.name() << ": not the old version's block";
    }
    auto batch = c.Post("/sets/s/batch?v=" + oldVersion, rebuilt[0].name(), "text/plain");
    ASSERT_TRUE(batch && batch->status == 200);
    EXPECT_EQ(batch->body.substr(4), bodies[rebuilt[0]]);
    auto hierarchy = c.Get("/sets/s/hierarchy.bin");
    ASSERT_TRUE(hierarchy && hierarchy->status == 200);
    EXPECT_TRUE(hierarchy->body == oldHierarchy) << "hierarchy.bin is the version before's";
    auto current = c.Get("/sets/s/" + after->info().hierarchyFile);
    ASSERT_TRUE(current && current->status == 200);
    EXPECT_TRUE(current->body == test::readFile(set() + "/" + after->info().hierarchyFile));
    auto stale = c.Get("/sets/s/nodes/" + rebuilt[0].name() + "?v=12345");
    ASSERT_TRUE(stale);
    EXPECT_EQ(stale->status, 409);
    ::kill(server.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(server.pid), 0);
}

// A kill at any moment of an update leaves the old set or the new one, whole
// (every block's checksum verified), never a mix; the next update clears
// what the killed ones left.
TEST_F(UpdateTest, KillAnywhereLeavesTheOldSetOrTheNewOne) {
    const std::string pristine = dir.file("pristine");
    fs::copy(set(), pristine, fs::copy_options::recursive);
    auto restore = [&] {
        fs::remove_all(set());
        fs::copy(pristine, set(), fs::copy_options::recursive);
    };
    const std::string oldJson = test::readFile(set() + "/tileset.json");
    const std::vector<std::string> update = {test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()};
    const auto t0 = std::chrono::steady_clock::now();
    auto r = test::run(update);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const std::string newJson = test::readFile(set() + "/tileset.json");
    ASSERT_NE(newJson, oldJson);
    restore();
    r = test::run(update);
    ASSERT_EQ(test::readFile(set() + "/tileset.json"), newJson) << "the update is not deterministic: the check below needs it to be";

    std::mt19937 random(34);
    std::map<std::string, int> outcomes;
    const int runs = test::kSanitized ? 6 : 20;
    for (int i = 0; i < runs; ++i) {
        restore();
        const double at = std::uniform_real_distribution<double>(0, 1.1 * seconds)(random);
        test::Child child = test::spawn(update);
        std::this_thread::sleep_for(std::chrono::duration<double>(at));
        ::kill(child.pid, SIGKILL);
        test::exitCode(child.pid);
        ::close(child.err);
        const std::string json = test::readFile(set() + "/tileset.json");
        const char* outcome = json == oldJson ? "old" : json == newJson ? "new" : "mixed";
        ++outcomes[outcome];
        EXPECT_NE(std::string(outcome), "mixed") << "killed after " << at << " s";
        auto reader = TilesetReader::open(set());
        ASSERT_TRUE(reader) << "killed after " << at << " s: " << reader.status().message();
        auto verified = verifyTileset(*reader);
        EXPECT_TRUE(verified) << "killed after " << at << " s: " << verified.status().message();
    }
    for (const auto& [what, n] : outcomes) std::printf("%s: %d\n", what.c_str(), n);
    // An update after one killed half way (which may leave its folder, and a
    // block file and hierarchy that no version names) finishes, and leaves
    // nothing of the other's.
    restore();
    test::Child child = test::spawn(update);
    std::this_thread::sleep_for(std::chrono::duration<double>(0.5 * seconds));
    ::kill(child.pid, SIGKILL);
    test::exitCode(child.pid);
    ::close(child.err);
    if (test::readFile(set() + "/tileset.json") != oldJson) restore();
    r = test::run(update);
    EXPECT_EQ(test::readFile(set() + "/tileset.json"), newJson);
    EXPECT_EQ(r.exitCode, 0) << r.output;
    ASSERT_NO_FATAL_FAILURE(expectNothingLeftBehind(set()));
}

// Bad input during an update: the set's files stay as they were, and the
// error names what is wrong.
TEST_F(UpdateTest, BadInputLeavesTheSetUntouched) {
    std::map<std::string, std::string> files;
    for (const auto& e : fs::directory_iterator(set())) files[e.path().filename().string()] = test::readFile(e.path().string());
    auto expectUntouched = [&](const std::string& when) {
        std::map<std::string, std::string> now;
        for (const auto& e : fs::directory_iterator(set())) now[e.path().filename().string()] = test::readFile(e.path().string());
        EXPECT_TRUE(now == files) << "the set changed after " << when;
    };

    // A truncated LAZ file.
    const std::string bytes = test::readFile(added[0]);
    const std::string broken = dir.file("broken.laz");
    test::writeFile(broken, bytes.substr(0, bytes.size() / 2));
    auto r = test::run({test::binary("surfcast-build"), "-q", "--add", broken, "--to", set()});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("broken.laz"), std::string::npos) << r.output;
    expectUntouched("a truncated input");

    // The added cell rewritten by laspy: `edit` runs on `las`, read from it, before it is written to `name`.
    auto rewritten = [&](const std::string& name, const std::string& edit) {
        auto w = test::run({SURFCAST_TEST_PYTHON, "-c", "import laspy, sys\nlas = laspy.read(sys.argv[1])\n" + edit + "las.write(sys.argv[2])\n",
                            added[0], dir.file(name)});
        EXPECT_EQ(w.exitCode, 0) << w.output;
        return dir.file(name);
    };

    // A scan the set's layout cannot take: the added cell with 16-bit
    // colour (c·256 + 1: no 8-bit value written either way LAS writers do),
    // where the set's blocks store 8 bits.
    const std::string deeper = rewritten("deeper.laz", "for c in ('red', 'green', 'blue'): las[c] = las[c].astype('uint32') * 256 + 1\n");
    r = test::run({test::binary("surfcast-build"), "-q", "--add", deeper, "--to", set()});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("change the colour depth (8 to 16 bits)"), std::string::npos) << r.output;
    expectUntouched("a scan the set's layout cannot take");

    // A scan in another coordinate system: the added cell declaring WGS 84
    // (a WKT VLR) where the set's cells declare autzen's (split_laz.py keeps them).
    const std::string elsewhere =
        rewritten("elsewhere.laz",
                  "las.header.vlrs = [v for v in las.header.vlrs if v.user_id != 'LASF_Projection']\n"
                  "las.header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr('GEOGCS[\"WGS 84\",DATUM[\"WGS_1984\","
                  "SPHEROID[\"WGS 84\",6378137,298.257223563]],PRIMEM[\"Greenwich\",0],UNIT[\"degree\",0.0174532925199433]]'))\n");
    r = test::run({test::binary("surfcast-build"), "-q", "--add", elsewhere, "--to", set()});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("elsewhere.laz: declares another coordinate system (WGS 84) than the set's inputs "
                            "(NAD_1983_HARN_Lambert_Conformal_Conic)"),
              std::string::npos)
        << r.output;
    expectUntouched("a scan in another coordinate system");

    // Build options are the set's own.
    r = test::run({test::binary("surfcast-build"), "--add", added[0], "--to", set(), "--grid", "64"});
    EXPECT_EQ(r.exitCode, 2) << r.output;
    EXPECT_NE(r.output.find("--grid"), std::string::npos) << r.output;
    // A set without a build record.
    fs::remove(set() + "/build.bin");
    files.erase("build.bin");
    r = test::run({test::binary("surfcast-build"), "-q", "--add", added[0], "--to", set()});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("build record"), std::string::npos) << r.output;
    expectUntouched("a set without its record");
}

}  // namespace
