// Updates in stages (preprocess/octree/update.h: update-plan, chunk,
// update-merge) and --merge, against fresh builds: compiled into update_test
// with update_test.cpp, whose fixture (update_support.h) they share.
#include <set>

#include "update_support.h"

using namespace surfcast;
using namespace surfcast::update_test;
namespace fs = std::filesystem;

namespace {

// --merge joins sets built apart: a build from their leaves equals a fresh
// build of all their inputs in the same sense as an update (the same leaf
// points: the count, positions within the quantizations, attributes exact,
// each set one input), with the first set's build options; --remove of a set
// gives back the other's points.
TEST_F(UpdateTest, MergeJoinsSetsBuiltApart) {
    auto r = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/split_laz.py", test::dataFile("autzen_trim.las"), dir.file("halves"),
                        "--cells", "2x1x1", "--min-files", "2"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const std::string west = dir.file("halves/r000000.laz"), east = dir.file("halves/r000001.laz");
    const std::string westSet = dir.file("sets/west"), eastSet = dir.file("sets/east"), merged = dir.file("sets/merged");
    ASSERT_EQ(test::run(build({west, "-o", westSet})).exitCode, 0);
    ASSERT_EQ(test::run(build({east, "-o", eastSet})).exitCode, 0);
    // Not a set: refused, and nothing written.
    r = test::run({test::binary("surfcast-build"), "-q", "--merge", westSet, dir.file("halves"), "-o", merged});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find(dir.file("halves") + ": not a tile set"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(merged));
    // A set with a corrupt block: refused, naming it, and nothing written.
    const std::string corrupt = dir.file("sets/corrupt");
    fs::copy(eastSet, corrupt, fs::copy_options::recursive);
    std::string blocks = test::readFile(corrupt + "/blocks.bin");
    blocks[blocks.size() / 2] ^= 0x5A;
    test::writeFile(corrupt + "/blocks.bin", blocks);
    r = test::run({test::binary("surfcast-build"), "-q", "--merge", westSet, corrupt, "-o", merged});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find(corrupt), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("CRC"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(merged));

    // (No build options given: the first set's, --memory 64M --capacity 1000.)
    r = test::run({test::binary("surfcast-build"), "-q", "--merge", westSet, eastSet, "-o", merged});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    ASSERT_EQ(test::run(build({west, east, "-o", dir.file("fresh")})).exitCode, 0);
    auto joined = TilesetReader::open(merged);
    auto fresh = TilesetReader::open(dir.file("fresh"));
    ASSERT_TRUE(joined && fresh);
    ASSERT_TRUE(verifyTileset(*joined));
    EXPECT_EQ(joined->info().inputs, (std::vector<std::string>{"west", "east"}));
    // The same capacity cuts the same nodes (the default's would cut far fewer).
    EXPECT_EQ(joined->nodes().size(), fresh->nodes().size());
    // Each quantization moves a point by at most half its step: the set's
    // own, then the joined set's, against the fresh build's; 1.5 of the
    // largest step bounds the three.
    double step = 0;
    std::vector<Point> westPoints, eastPoints, joinedPoints, expected;
    ASSERT_NO_FATAL_FAILURE(leafPoints(westSet, &step, &westPoints));
    ASSERT_NO_FATAL_FAILURE(leafPoints(eastSet, &step, &eastPoints));
    ASSERT_NO_FATAL_FAILURE(leafPoints(merged, &step, &joinedPoints));
    ASSERT_NO_FATAL_FAILURE(leafPoints(dir.file("fresh"), &step, &expected));
    ASSERT_EQ(joinedPoints.size(), expected.size());
    ASSERT_EQ(joinedPoints.size(), westPoints.size() + eastPoints.size());
    EXPECT_EQ(matchPoints(expected, joinedPoints, 1.5 * step), expected.size()) << "leaf step " << step;

    // How the first set read its inputs acts on its points no more: built
    // at --opacity 0.5, its points keep opacity 128 in the joined set (not 64).
    const std::string translucent = dir.file("sets/translucent"), joined2 = dir.file("sets/joined2");
    ASSERT_EQ(test::run(build({west, "--opacity", "0.5", "-o", translucent})).exitCode, 0);
    r = test::run({test::binary("surfcast-build"), "-q", "--merge", translucent, eastSet, "-o", joined2});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto second = TilesetReader::open(joined2);
    ASSERT_TRUE(second);
    std::map<int, std::set<int>> opacities;  // by input
    for (const NodeRecord& n : second->nodes()) {
        if (!(n.flags & kFlagInputPoints)) continue;
        auto block = second->readBlock(n, true);
        ASSERT_TRUE(block) << block.status().message();
        ASSERT_FALSE(block->opacity.empty());
        auto input = std::find_if(block->scalars.begin(), block->scalars.end(), [](const ScalarAttribute& a) { return a.name == "input"; });
        ASSERT_NE(input, block->scalars.end());
        for (size_t i = 0; i < block->size(); ++i) opacities[int(input->values.at(i))].insert(block->opacity[i]);
    }
    EXPECT_EQ(opacities[0], (std::set<int>{128}));
    EXPECT_EQ(opacities[1], (std::set<int>{255}));

    r = test::run({test::binary("surfcast-build"), "-q", "--remove", "east", "--to", merged});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::vector<Point> left;
    ASSERT_NO_FATAL_FAILURE(leafPoints(merged, &step, &left));
    for (Point& p : westPoints) p.input = 0;
    ASSERT_NO_FATAL_FAILURE(expectSamePoints(westPoints, left, step));
}

// Byte-identical to a fresh build where the chunk plan is unchanged: every
// node of a chunk the update keeps (one the added points and their halos do
// not reach, in the plan of all the inputs) holds the bytes the fresh build
// writes for its key, as both read the same points there and build
// deterministically. Nodes of the rebuilt chunks are not: they are built from
// the set's leaves, quantized once more and with the normals far from the
// change kept (a rebuilt node may still keep its old place where it encodes
// to its old bytes). The update runs in stages here, whose plan.json names
// the chunks (the same bytes as in one process: dask_test).
TEST_F(UpdateTest, KeptChunksAreByteIdenticalToAFreshBuild) {
    const std::string work = dir.file("work");
    auto r = test::run({test::binary("surfcast-build"), "update-plan", "-q", "--work", work, "--add", added[0], "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const nlohmann::json plan = nlohmann::json::parse(test::readFile(work + "/plan.json"));
    std::vector<std::string> command = {test::binary("surfcast-build"), "chunk", "-q", "--work", work};
    std::set<size_t> rebuilt;
    for (size_t i : plan["build"]) rebuilt.insert(i), command.push_back(std::to_string(i));
    ASSERT_EQ(test::run(command).exitCode, 0);
    // A chunk the update keeps is not built.
    size_t keptIndex = 0;
    while (rebuilt.count(keptIndex)) ++keptIndex;
    r = test::run({test::binary("surfcast-build"), "chunk", "-q", "--work", work, std::to_string(keptIndex)});
    EXPECT_EQ(r.exitCode, 2) << r.output;
    EXPECT_NE(r.output.find("the update keeps it"), std::string::npos) << r.output;
    r = test::run({test::binary("surfcast-build"), "update-merge", "-q", "--work", work});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    // Run again after the switch (a task Dask repeats): the set holds the update, and stays.
    const std::string tileset = test::readFile(set() + "/tileset.json");
    r = test::run({test::binary("surfcast-build"), "update-merge", "-q", "--work", work});
    EXPECT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("holds this update already"), std::string::npos) << r.output;
    EXPECT_EQ(test::readFile(set() + "/tileset.json"), tileset);
    auto all = base;
    all.insert(all.end(), added.begin(), added.end());
    all.insert(all.end(), {"-o", dir.file("fresh")});
    ASSERT_EQ(test::run(build(all)).exitCode, 0);

    std::vector<NodeKey> keptChunks;
    for (size_t i = 0; i < plan["chunk_nodes"].size(); ++i) {
        NodeKey key;
        ASSERT_TRUE(NodeKey::parse(plan["chunk_nodes"][i].get<std::string>(), &key));
        if (!rebuilt.count(i)) keptChunks.push_back(key);
    }
    ASSERT_FALSE(keptChunks.empty());
    ASSERT_FALSE(rebuilt.empty());
    auto inKeptChunk = [&](const NodeKey& key) {
        return std::any_of(keptChunks.begin(), keptChunks.end(), [&](const NodeKey& chunk) {
            const int below = int(key.level) - int(chunk.level);
            return below >= 0 && (key.x >> below) == chunk.x && (key.y >> below) == chunk.y && (key.z >> below) == chunk.z;
        });
    };
    auto after = TilesetReader::open(set());
    auto fresh = TilesetReader::open(dir.file("fresh"));
    ASSERT_TRUE(after && fresh);
    std::map<NodeKey, NodeRecord> freshNodes;
    for (const NodeRecord& n : fresh->nodes()) freshNodes[n.key] = n;
    size_t compared = 0;
    for (const NodeRecord& n : after->nodes()) {
        if (!inKeptChunk(n.key)) continue;
        auto it = freshNodes.find(n.key);
        ASSERT_NE(it, freshNodes.end()) << n.key.name() << " is in a kept chunk but not in the fresh build";
        EXPECT_EQ(n.blockCrc, it->second.blockCrc) << n.key.name();
        EXPECT_EQ(n.blockSize, it->second.blockSize) << n.key.name();
        ++compared;
    }
    EXPECT_GT(compared, 0u);
    // And every node of a kept chunk: the fresh build has none there the update lacks.
    size_t inKept = 0;
    for (const NodeRecord& n : fresh->nodes()) inKept += inKeptChunk(n.key);
    EXPECT_EQ(inKept, compared);
}

// An update in stages (update.h) holds for the version of the set it was
// planned on: where another update switched the set after update-plan, the
// chunk and update-merge stages fail, naming the set, and leave it as that
// update left it.
TEST_F(UpdateTest, StagedUpdateFailsWhereTheSetChangedAfterItsPlan) {
    const std::string work = dir.file("work");
    auto r = test::run({test::binary("surfcast-build"), "update-plan", "-q", "--work", work, "--add", added[0], "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    ASSERT_NE(r.output.find("chunks to build"), std::string::npos) << r.output;
    r = test::run({test::binary("surfcast-build"), "-q", "--remove", base[0], "--to", set()});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::map<std::string, std::string> files;
    for (const auto& e : fs::directory_iterator(set())) files[e.path().filename().string()] = test::readFile(e.path().string());

    r = test::run({test::binary("surfcast-build"), "chunk", "-q", "--work", work, "0"});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find(set() + ": changed since this update was planned"), std::string::npos) << r.output;
    r = test::run({test::binary("surfcast-build"), "update-merge", "-q", "--work", work});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find(set() + ": changed since this update was planned"), std::string::npos) << r.output;
    std::map<std::string, std::string> now;
    for (const auto& e : fs::directory_iterator(set())) now[e.path().filename().string()] = test::readFile(e.path().string());
    EXPECT_TRUE(now == files);
    // A build's merge refuses the update's work folder.
    r = test::run({test::binary("surfcast-build"), "merge", "-q", "--work", work});
    EXPECT_EQ(r.exitCode, 2) << r.output;
    EXPECT_NE(r.output.find("holds an update's plan"), std::string::npos) << r.output;
}

}  // namespace
