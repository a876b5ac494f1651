// The staged build (preprocess/octree/stages.h): surfcast-build plan,
// distribute, chunk and merge, each its own process, write the same bytes as
// one surfcast-build, and refuse work files that are missing or corrupt.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include "test_support.h"
#include "tileset_format.h"
#include "work_files.h"

using namespace surfcast;
namespace fs = std::filesystem;

namespace {

std::vector<std::string> concat(std::vector<std::string> a, const std::vector<std::string>& b) {
    a.insert(a.end(), b.begin(), b.end());
    return a;
}

// Runs one stage; its output on failure.
void stage(const std::vector<std::string>& args) {
    auto r = test::run(concat({test::binary("surfcast-build")}, args));
    ASSERT_EQ(r.exitCode, 0) << r.output;
}

// The chunk count plan.json announces.
size_t plannedChunks(const std::string& work) {
    const std::string json = test::readFile(work + "/plan.json");
    const size_t at = json.find("\"chunks\": ");
    if (at == std::string::npos) return 0;
    return size_t(std::stoul(json.substr(at + 10)));
}

// The parts plan.json lists that start within a file (a cut LAS or LAZ file).
size_t partsStartingWithinAFile(const std::string& work) {
    const std::string json = test::readFile(work + "/plan.json");
    size_t n = 0;
    for (size_t at = json.find("\"begin\": "); at != std::string::npos; at = json.find("\"begin\": ", at + 1))
        n += std::stoull(json.substr(at + 9)) > 0;  // past "begin": and the space
    return n;
}

void expectSameSet(const std::string& a, const std::string& b) {
    for (const char* file : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        EXPECT_TRUE(test::readFile(a + "/" + file) == test::readFile(b + "/" + file)) << file << " differs between " << a << " and " << b;
}

// The staged build of `options` in `dir`: the inputs scanned, counted and
// distributed in `parts` parts (the distribution last part first), the chunks
// built last to first (an order no single process uses), the first of them
// twice, as a retried task would; then compared with one process's build.
// `cuts`: the parts that should start within a file.
void expectStagedSameAsOneProcess(const test::TempDir& dir, const std::vector<std::string>& options, size_t minChunks = 4,
                                  size_t cuts = 0, int parts = 3) {
    const std::string work = dir.file("work");
    auto whole = test::run(concat(concat({test::binary("surfcast-build"), "-q"}, options), {"-o", dir.file("whole")}));
    ASSERT_EQ(whole.exitCode, 0) << whole.output;
    const std::vector<std::string> output = {"-o", dir.file("staged")};
    const std::string n = std::to_string(parts);
    for (const char* stageName : {"scan", "count"})
        for (int part = 0; part < parts; ++part)
            ASSERT_NO_FATAL_FAILURE(stage(concat(concat({stageName, "--work", work, "-q", "--part", std::to_string(part) + "/" + n}, options), output)));
    ASSERT_NO_FATAL_FAILURE(stage(concat(concat({"plan", "--work", work, "-q", "--parts", n}, options), output)));
    const size_t chunks = plannedChunks(work);
    ASSERT_GE(chunks, minChunks) << "the budget should force several chunks";
    EXPECT_EQ(partsStartingWithinAFile(work), cuts) << test::readFile(work + "/plan.json");
    // The chunks reported are the chunks built.
    EXPECT_NE(whole.output.find(" " + std::to_string(chunks) + " chunks"), std::string::npos) << whole.output;
    for (int part = parts - 1; part >= 0; --part) ASSERT_NO_FATAL_FAILURE(stage({"distribute", "--work", work, "-q", "--part", std::to_string(part)}));
    for (size_t i = chunks; i-- > 0;) ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", std::to_string(i)}));
    ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", std::to_string(chunks - 1)}));
    ASSERT_NO_FATAL_FAILURE(stage({"merge", "--work", work, "-q"}));
    expectSameSet(dir.file("staged"), dir.file("whole"));
}

void flipByte(const std::string& path, uint64_t at) {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(std::streamoff(at));
    char c = 0;
    f.get(c);
    f.seekp(std::streamoff(at));
    f.put(char(c ^ 0x20));
}

}  // namespace

TEST(Stages, DefaultSceneAcrossChunksSameBytesAsOneProcess) {
    test::TempDir dir;
    expectStagedSameAsOneProcess(dir, {"--default-scene", "--scene-points", "300000", "--memory", "160M", "--capacity", "4000"});
}

// Versions while building (refine.h) in stages: distribute writes the
// stand-ins aside (--stand-ins N), refine publishes the chunks built so far
// with the others' stand-ins, a whole set marked with the share done; the
// set the merge then writes is the one-process build's, byte for byte, and
// the work folder keeps no stand-in. No version replaces a finished set.
TEST(Stages, VersionsWhileBuildingLeaveTheSameBytes) {
    test::TempDir dir;
    const std::vector<std::string> options = {"--default-scene", "--scene-points", "300000", "--memory", "160M", "--capacity", "4000"};
    const std::string work = dir.file("work"), out = dir.file("staged");
    auto whole = test::run(concat(concat({test::binary("surfcast-build"), "-q"}, options), {"-o", dir.file("whole")}));
    ASSERT_EQ(whole.exitCode, 0) << whole.output;
    ASSERT_NO_FATAL_FAILURE(stage(concat(concat({"plan", "--work", work, "-q"}, options), {"-o", out})));
    const size_t chunks = plannedChunks(work);
    ASSERT_GE(chunks, 4u);
    ASSERT_NO_FATAL_FAILURE(stage({"distribute", "--work", work, "-q", "--stand-ins", "30"}));
    for (size_t i = 0; i < chunks / 2; ++i) ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", std::to_string(i)}));
    // Over a finished set no version is written.
    fs::copy(dir.file("whole"), out, fs::copy_options::recursive);
    auto refused = test::run({test::binary("surfcast-build"), "refine", "--work", work, "-q", "--stand-ins", "30"});
    EXPECT_EQ(refused.exitCode, 1) << refused.output;
    EXPECT_NE(refused.output.find("which no version of a build replaces"), std::string::npos) << refused.output;
    expectSameSet(out, dir.file("whole"));
    fs::remove_all(out);
    auto refined = test::run({test::binary("surfcast-build"), "refine", "--work", work, "-q", "--stand-ins", "30"});
    ASSERT_EQ(refined.exitCode, 0) << refined.output;
    EXPECT_NE(refined.output.find(std::to_string(chunks / 2) + " of " + std::to_string(chunks) + " chunks built"), std::string::npos)
        << refined.output;
    auto version = readTilesetJson(test::readFile(out + "/tileset.json"), "tileset.json");
    ASSERT_TRUE(version) << version.status().message();
    EXPECT_EQ(version->previewStride, 30u);
    EXPECT_GT(version->previewDone, 0);
    EXPECT_LT(version->previewDone, 1);
    auto info = test::run({test::binary("surfcast-build"), "--info", out});
    EXPECT_EQ(info.exitCode, 0) << info.output;  // every block's CRC checks
    for (size_t i = chunks / 2; i < chunks; ++i) ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", std::to_string(i)}));
    ASSERT_NO_FATAL_FAILURE(stage({"merge", "--work", work, "-q"}));
    expectSameSet(out, dir.file("whole"));
    EXPECT_FALSE(fs::exists(work + "/stand-ins"));
    auto finished = readTilesetJson(test::readFile(out + "/tileset.json"), "tileset.json");
    ASSERT_TRUE(finished) << finished.status().message();
    EXPECT_EQ(finished->previewStride, 0u);

    // refine wants the stride distribute was given.
    auto bare = test::run({test::binary("surfcast-build"), "refine", "--work", work});
    EXPECT_EQ(bare.exitCode, 2) << bare.output;
    EXPECT_NE(bare.output.find("--stand-ins"), std::string::npos) << bare.output;
}

// Inputs of three formats in three parts: the scene (several scanners, so a
// part's sources are not its inputs), a LAZ scan and a PCD scan. They lie far
// apart, each within one cell of the counting grid: a chunk each.
TEST(Stages, InputsInPartsSameBytesAsOneProcess) {
    REQUIRE_DATA();
    test::TempDir dir;
    expectStagedSameAsOneProcess(dir, {"--default-scene", "--scene-points", "200000", test::dataFile("Megaplot.laz"),
                                       test::dataFile("fragment.pcd"), "--memory", "100M", "--capacity", "4000"},
                                 3);
}

// One COPC file (variable LAZ chunks) cut into three parts at its chunks,
// and a LAS file in four parts: its one cut, at 65,536 records, ends part 0;
// part 1 is empty there, part 2 starts there and part 3 is empty at the end.
// Each part reads its run of records on its own.
TEST(Stages, FilesCutIntoPartsSameBytesAsOneProcess) {
    REQUIRE_DATA();
    {
        test::TempDir dir;
        expectStagedSameAsOneProcess(dir, {test::dataFile("lion_takanawa.copc.laz"), "--memory", "128M", "--capacity", "2000"}, 4, 2);
    }
    test::TempDir dir;
    expectStagedSameAsOneProcess(dir, {test::dataFile("autzen_trim.las"), "--memory", "64M", "--capacity", "1000"}, 2, 2, 4);
}

// A LAZ scan with its scalar fields (gps_time, scan_angle), cut into parts:
// the chunk roots carry their rows to the merge.
TEST(Stages, ScalarFieldsSameBytesAsOneProcess) {
    REQUIRE_DATA();
    test::TempDir dir;
    expectStagedSameAsOneProcess(dir, {test::dataFile("Megaplot.laz"), "--attributes", "all", "--memory", "64M", "--capacity", "1000"},
                                 4, 1);  // its two LAZ chunks, one part each
}

// A textured mesh fitted by least squares: every stage's process rebuilds
// the texture field from the mesh, and the fits' reports travel with the chunks.
TEST(Stages, TexturedMeshSameBytesAsOneProcess) {
    REQUIRE_DATA();
    test::TempDir dir;
    expectStagedSameAsOneProcess(dir, {test::dataFile("fg_spkMgDragon/fg_spkMgDragon.obj"), "--mesh-max-surfels", "100000",
                                       "--memory", "230M", "--capacity", "2000"});
}

TEST(Stages, MissingOrCorruptWorkFilesFailWithTheirNames) {
    test::TempDir dir;
    const std::string work = dir.file("work"), out = dir.file("set");
    const std::string build = test::binary("surfcast-build");
    // An old set at the output, which no failed merge may touch.
    auto old = test::buildScene(out, 20000);
    ASSERT_EQ(old.exitCode, 0) << old.output;
    const std::string oldBlocks = test::readFile(out + "/blocks.bin");

    // Usage: no work folder; build options on a later stage; a chunk the plan lacks.
    EXPECT_EQ(test::run({build, "distribute"}).exitCode, 2);
    auto merged = test::run({build, "merge", "--work", work});
    EXPECT_EQ(merged.exitCode, 1);
    EXPECT_NE(merged.output.find(work + "/plan.bin"), std::string::npos) << merged.output;
    ASSERT_NO_FATAL_FAILURE(stage({"plan", "--work", work, "-q", "--default-scene", "--scene-points", "200000", "--memory", "160M",
                                   "--capacity", "4000", "-o", out}));
    const size_t chunks = plannedChunks(work);
    ASSERT_GE(chunks, 2u);
    auto option = test::run({build, "chunk", "--work", work, "--grid", "64", "0"});
    EXPECT_EQ(option.exitCode, 2);
    EXPECT_NE(option.output.find("not --grid"), std::string::npos) << option.output;
    auto range = test::run({build, "chunk", "--work", work, std::to_string(chunks)});
    EXPECT_EQ(range.exitCode, 2) << range.output;

    // Parts: a count before every scan; a plan of more parts than were scanned.
    const std::vector<std::string> scene = {"--default-scene", "--scene-points", "200000", "--memory", "160M", "--capacity", "4000", "-o", out};
    const std::string parted = dir.file("parted");
    ASSERT_NO_FATAL_FAILURE(stage(concat({"scan", "--work", parted, "-q", "--part", "0/2"}, scene)));
    auto unscanned = test::run(concat({build, "count", "--work", parted, "--part", "0/2"}, scene));
    EXPECT_EQ(unscanned.exitCode, 1);
    EXPECT_NE(unscanned.output.find(parted + "/scan/1.bin"), std::string::npos) << unscanned.output;
    auto badPart = test::run(concat({build, "scan", "--work", parted, "--part", "2/2"}, scene));
    EXPECT_EQ(badPart.exitCode, 2) << badPart.output;
    // A part scanned with other options is another build's: never reduced with this one's.
    std::vector<std::string> other = scene;
    other[2] = "210000";
    ASSERT_NO_FATAL_FAILURE(stage(concat({"scan", "--work", parted, "-q", "--part", "1/2"}, other)));
    auto mixed = test::run(concat({build, "count", "--work", parted, "--part", "0/2"}, scene));
    EXPECT_EQ(mixed.exitCode, 1);
    EXPECT_NE(mixed.output.find(parted + "/scan/1.bin: scanned for another build"), std::string::npos) << mixed.output;

    // A chunk before its points are distributed, the merge before a chunk is built.
    auto early = test::run({build, "chunk", "--work", work, "0"});
    EXPECT_EQ(early.exitCode, 1);
    EXPECT_NE(early.output.find("/chunks/0/distribution.bin"), std::string::npos) << early.output;
    ASSERT_NO_FATAL_FAILURE(stage({"distribute", "--work", work, "-q"}));
    for (size_t i = 1; i < chunks; ++i) ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", std::to_string(i)}));
    auto missing = test::run({build, "merge", "--work", work, "-q"});
    EXPECT_EQ(missing.exitCode, 1);
    EXPECT_NE(missing.output.find("nodes/0.nodes"), std::string::npos) << missing.output;
    ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", "0"}));

    // A flipped byte in a chunk's blocks: the merge names the file and the node.
    const std::string blocks = work + "/nodes/0.blocks";
    flipByte(blocks, std::filesystem::file_size(blocks) / 2);
    auto corrupt = test::run({build, "merge", "--work", work, "-q"});
    EXPECT_EQ(corrupt.exitCode, 1);
    EXPECT_NE(corrupt.output.find(blocks + ": the block of node"), std::string::npos) << corrupt.output;
    EXPECT_NE(corrupt.output.find("fails its CRC"), std::string::npos) << corrupt.output;
    // A truncated record file (a copy cut short): its checksum fails.
    const std::string nodes = work + "/nodes/1.nodes";
    std::filesystem::resize_file(nodes, std::filesystem::file_size(nodes) - 7);
    auto truncated = test::run({build, "merge", "--work", work, "-q"});
    EXPECT_EQ(truncated.exitCode, 1);
    EXPECT_NE(truncated.output.find(nodes + ": checksum mismatch"), std::string::npos) << truncated.output;
    EXPECT_TRUE(test::readFile(out + "/blocks.bin") == oldBlocks) << "a failed merge changed the old set";

    // A node's record without a block (as a node an update keeps has) in a
    // build's chunk: the merge names the file and the node.
    ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", "0", "1"}));
    {
        auto output = readChunkOutput(nodes, ScalarTable{});
        ASSERT_TRUE(output) << output.status().message();
        ASSERT_FALSE(output->records.empty());
        const std::string key = output->records.back().key.name();
        output->records.back().blockSize = 0;
        ASSERT_TRUE(writeChunkOutput(nodes, *output).ok());
        auto blockless = test::run({build, "merge", "--work", work, "-q"});
        EXPECT_EQ(blockless.exitCode, 1);
        EXPECT_NE(blockless.output.find(nodes + ": node " + key + " has no block"), std::string::npos) << blockless.output;
    }

    // A chunk built for an earlier plan (its files copied back after a new
    // plan of the same layout): the merge refuses it.
    ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", "0", "1"}));
    const std::string saved = dir.file("saved");
    fs::create_directories(saved);
    for (const char* name : {"1.nodes", "1.blocks"}) fs::copy_file(work + "/nodes/" + name, saved + "/" + name);
    ASSERT_NO_FATAL_FAILURE(stage({"plan", "--work", work, "-q", "--default-scene", "--scene-points", "200000", "--memory", "160M",
                                   "--capacity", "4000", "--normal-bits", "9", "-o", out}));
    EXPECT_FALSE(fs::exists(work + "/nodes")) << "a new plan should clear the chunks built to the old one";
    ASSERT_NO_FATAL_FAILURE(stage({"distribute", "--work", work, "-q"}));
    for (size_t i = 0; i < chunks; ++i) ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", std::to_string(i)}));
    for (const char* name : {"1.nodes", "1.blocks"}) fs::copy_file(saved + "/" + name, work + "/nodes/" + name, fs::copy_options::overwrite_existing);
    auto stale = test::run({build, "merge", "--work", work, "-q"});
    EXPECT_EQ(stale.exitCode, 1);
    EXPECT_NE(stale.output.find(work + "/nodes/1.nodes: built for another plan"), std::string::npos) << stale.output;
    EXPECT_TRUE(test::readFile(out + "/blocks.bin") == oldBlocks) << "a failed merge changed the old set";

    // Built again, every chunk merges into the new set.
    ASSERT_NO_FATAL_FAILURE(stage({"chunk", "--work", work, "-q", "1"}));
    ASSERT_NO_FATAL_FAILURE(stage({"merge", "--work", work, "-q"}));
    auto info = test::run({build, "--info", out});
    EXPECT_EQ(info.exitCode, 0) << info.output;
    EXPECT_NE(info.output.find("checksums verified"), std::string::npos) << info.output;
}
