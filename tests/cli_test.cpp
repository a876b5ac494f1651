#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>

#include <nlohmann/json.hpp>

#include "test_support.h"
#include "tileset_reader.h"
#include "tileset_writer.h"

using namespace surfcast;

namespace {

// Every file of a set's folder, by name.
std::map<std::string, std::string> setFiles(const std::string& dir) {
    std::map<std::string, std::string> files;
    for (const auto& e : std::filesystem::directory_iterator(dir)) files[e.path().filename().string()] = test::readFile(e.path().string());
    return files;
}

}  // namespace

// The four programs share one command line library: --version names the
// project's version (CMakeLists.txt's project()) and the format versions,
// --help starts with the usage, a usage error exits 2 pointing at --help.
TEST(Cli, EveryProgramAnswersVersionHelpAndUsageErrorsAlike) {
    const std::string cmake = test::readFile(std::string(SURFCAST_TEST_TOOLS) + "/../../CMakeLists.txt");
    std::smatch m;
    ASSERT_TRUE(std::regex_search(cmake, m, std::regex(R"(project\(Surfcast VERSION ([0-9.]+))")));
    const std::string version = m[1];
    for (const std::string program : {"surfcast-build", "surfcast-serve", "surfcast-view", "surfcast-export"}) {
        auto v = test::run({test::binary(program), "--version"});
        EXPECT_EQ(v.exitCode, 0) << program;
        EXPECT_EQ(v.output.rfind(program + " " + version + "\n", 0), 0u) << v.output;
        EXPECT_NE(v.output.find("tile sets: reads format versions 1 to 3, writes 2"), std::string::npos) << v.output;
        auto h = test::run({test::binary(program), "--help"});
        EXPECT_EQ(h.exitCode, 0) << program;
        EXPECT_EQ(h.output.rfind("usage: " + program, 0), 0u) << h.output;
        EXPECT_NE(h.output.find("--version"), std::string::npos) << h.output;
        auto bad = test::run({test::binary(program), "/tmp", "--no-such-option"});
        EXPECT_EQ(bad.exitCode, 2) << program;
        EXPECT_NE(bad.output.find(program + ": unknown option --no-such-option\n(see " + program + " --help)"), std::string::npos)
            << bad.output;
    }
}

// Arguments reach the build as given, whatever the parser allows: an
// option's "--name=value" form is stored as "--name value" (so the parts of
// a staged build agree on what they build), a stage is named first or not at
// all, a positional is never split as a list, --help wins over a bad value,
// and "--" is no option.
TEST(Cli, ArgumentsReachTheBuildAsGiven) {
    const std::string build = test::binary("surfcast-build");
    test::TempDir dir;
    const std::string work = dir.file("work"), out = dir.file("set");
    auto scan = test::run({build, "scan", "--work", work, "--part", "0/1", "-q", "--grid=64", "--default-scene", "--scene-points", "3000",
                           "-o", out});
    ASSERT_EQ(scan.exitCode, 0) << scan.output;
    auto plan = test::run({build, "plan", "--work", work, "--parts", "1", "-q", "--grid", "64", "--default-scene", "--scene-points",
                           "3000", "-o", out});
    // (3,000 points make one chunk: no count.) Another job's scan would be refused.
    EXPECT_EQ(plan.exitCode, 0) << plan.output;

    auto stageLater = test::run({build, "--default-scene", "plan", "-o", out});
    EXPECT_EQ(stageLater.exitCode, 1) << stageLater.output;
    EXPECT_NE(stageLater.output.find("plan: no such file"), std::string::npos) << stageLater.output;
    auto bracketed = test::run({build, "[a,b]", "-o", out});
    EXPECT_EQ(bracketed.exitCode, 1) << bracketed.output;
    EXPECT_NE(bracketed.output.find("[a,b]: no such file"), std::string::npos) << bracketed.output;
    auto help = test::run({build, "--grid", "1", "--help"});
    EXPECT_EQ(help.exitCode, 0) << help.output;
    EXPECT_EQ(help.output.rfind("usage: surfcast-build", 0), 0u) << help.output;
    auto dashes = test::run({build, "--default-scene", "-o", out, "--", "--grid", "8"});
    EXPECT_EQ(dashes.exitCode, 2) << dashes.output;
    EXPECT_NE(dashes.output.find("unknown option --"), std::string::npos) << dashes.output;
    auto flagValue = test::run({build, "--default-scene", "-o", out, "--quiet=false"});
    EXPECT_EQ(flagValue.exitCode, 2) << flagValue.output;
    auto pluses = test::run({build, "chunk", "--work", work, "3", "++", "--grid", "8"});
    EXPECT_EQ(pluses.exitCode, 2) << pluses.output;
    EXPECT_NE(pluses.output.find("unknown option ++"), std::string::npos) << pluses.output;
    // A stage's own name later on is an input of that stage, not the stage again.
    auto twice = test::run({build, "plan", "--work", dir.file("w2"), "-q", "-o", out, "plan"});
    EXPECT_EQ(twice.exitCode, 1) << twice.output;
    EXPECT_NE(twice.output.find("plan: no such file"), std::string::npos) << twice.output;
    // A stage answers --help with its own usage, and --version as the program does.
    auto stageHelp = test::run({build, "chunk", "--help"});
    EXPECT_EQ(stageHelp.exitCode, 0) << stageHelp.output;
    EXPECT_EQ(stageHelp.output.rfind("usage: surfcast-build chunk", 0), 0u) << stageHelp.output;
    auto stageVersion = test::run({build, "plan", "--version"});
    EXPECT_EQ(stageVersion.exitCode, 0) << stageVersion.output;
    EXPECT_EQ(stageVersion.output.rfind("surfcast-build ", 0), 0u) << stageVersion.output;
}

TEST(Cli, HelpAndUsageErrors) {
    auto help = test::run({test::binary("surfcast-build"), "--help"});
    EXPECT_EQ(help.exitCode, 0);
    EXPECT_NE(help.output.find("usage: surfcast-build"), std::string::npos);
    auto unknown = test::run({test::binary("surfcast-build"), "--bogus"});
    EXPECT_EQ(unknown.exitCode, 2);
    EXPECT_NE(unknown.output.find("unknown option --bogus"), std::string::npos);
    auto noOut = test::run({test::binary("surfcast-build"), "--default-scene"});
    EXPECT_EQ(noOut.exitCode, 2);
    auto badMem = test::run({test::binary("surfcast-build"), "--default-scene", "-o", "/tmp/x", "--memory", "lots"});
    EXPECT_EQ(badMem.exitCode, 2);
    // Isolation under 1 would draw isolated surfels wider than the rest of their node.
    auto badIsolation = test::run({test::binary("surfcast-build"), "--default-scene", "-o", "/tmp/x", "--isolation", "0.5"});
    EXPECT_EQ(badIsolation.exitCode, 2);
    EXPECT_NE(badIsolation.output.find("--isolation needs 0 or a value in [1, 1000]"), std::string::npos) << badIsolation.output;
    // Outlier removal reads each point's 8th neighbour among the normals' k: with 8 or fewer it would judge nothing.
    auto blind = test::run({test::binary("surfcast-build"), "--default-scene", "-o", "/tmp/x", "--remove-outliers", "2", "--normal-k", "8"});
    EXPECT_EQ(blind.exitCode, 2);
    EXPECT_NE(blind.output.find("--remove-outliers needs --normal-k above --spacing-k (8 is not above 8)"), std::string::npos) << blind.output;
    auto negative = test::run({test::binary("surfcast-build"), "--default-scene", "-o", "/tmp/x", "--remove-outliers", "-1"});
    EXPECT_EQ(negative.exitCode, 2);
}

TEST(Cli, InfoVerifiesChecksums) {
    test::TempDir dir;
    auto b = test::run({test::binary("surfcast-build"), "--default-scene", "--scene-points", "50000", "-o", dir.file("s")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    EXPECT_NE(b.output.find("level 0:"), std::string::npos) << b.output;
    EXPECT_NE(b.output.find("peak RSS"), std::string::npos) << b.output;
    auto info = test::run({test::binary("surfcast-build"), "--info", dir.file("s")});
    ASSERT_EQ(info.exitCode, 0) << info.output;
    EXPECT_NE(info.output.find("checksums verified"), std::string::npos) << info.output;

    // Flip one byte in the middle of blocks.bin: --info names the node and the CRC.
    std::string blocks = dir.file("s/blocks.bin");
    auto size = std::filesystem::file_size(blocks);
    std::fstream f(blocks, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(std::streamoff(size / 2));
    char c = 0;
    f.get(c);
    f.seekp(std::streamoff(size / 2));
    f.put(char(c ^ 0x10));
    f.close();
    auto bad = test::run({test::binary("surfcast-build"), "--info", dir.file("s")});
    EXPECT_EQ(bad.exitCode, 1);
    EXPECT_NE(bad.output.find("CRC mismatch"), std::string::npos) << bad.output;
}

TEST(Cli, RefusesToReplaceSomethingElse) {
    test::TempDir dir;
    std::filesystem::create_directories(dir.file("precious"));
    test::writeFile(dir.file("precious/data.txt"), "keep me");
    auto r = test::run({test::binary("surfcast-build"), "--default-scene", "--scene-points", "1000", "-o", dir.file("precious")});
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("not a tile set"), std::string::npos) << r.output;
    EXPECT_EQ(test::readFile(dir.file("precious/data.txt")), "keep me");
}

TEST(Cli, FoldersAndListsOfInputs) {
    test::TempDir dir;
    // Three small text scans: two in a folder tree (with a file no reader takes),
    // one named by a list with a relative path, a comment and a blank line.
    std::filesystem::create_directories(dir.file("scans/deeper"));
    auto xyz = [&](const std::string& path, int n, double z) {
        std::string text;
        for (int i = 0; i < n; ++i) text += std::to_string(i * 0.01) + " " + std::to_string((i % 7) * 0.01) + " " + std::to_string(z) + "\n";
        test::writeFile(path, text);
    };
    xyz(dir.file("scans/a.xyz"), 100, 0);
    xyz(dir.file("scans/deeper/b.xyz"), 200, 1);
    test::writeFile(dir.file("scans/notes.md"), "not a scan");
    xyz(dir.file("c.xyz"), 300, 2);
    test::writeFile(dir.file("list.txt"), "# inputs\n\nc.xyz\n");
    auto r = test::run({test::binary("surfcast-build"), "-q", dir.file("scans"), "@" + dir.file("list.txt"), "-o", dir.file("s")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("points in: 600 "), std::string::npos) << r.output;

    auto missing = test::run({test::binary("surfcast-build"), "@" + dir.file("nope.txt"), "-o", dir.file("t")});
    EXPECT_EQ(missing.exitCode, 1);
    EXPECT_NE(missing.output.find("nope.txt: cannot open the input list"), std::string::npos) << missing.output;
    std::filesystem::create_directories(dir.file("empty"));
    auto empty = test::run({test::binary("surfcast-build"), dir.file("empty"), "-o", dir.file("t")});
    EXPECT_EQ(empty.exitCode, 1);
    EXPECT_NE(empty.output.find("holds no file of a readable format"), std::string::npos) << empty.output;
    EXPECT_FALSE(std::filesystem::exists(dir.file("t")));
}

// Every writer of a set takes the lock on its folder that updates take
// (an exclusive flock, held until it ends): while another writer holds it, a
// rebuild with -o, --merge, a staged build's merge, an update and a
// compaction fail at once, naming the set, and leave it as it was.
TEST(Cli, WritersOfASetFailWhileAnotherHoldsItsLock) {
    test::TempDir dir;
    const std::string set = dir.file("s"), other = dir.file("t"), work = dir.file("work");
    const std::string build = test::binary("surfcast-build");
    for (const std::string& out : {set, other}) {
        auto r = test::run({build, "-q", "--default-scene", "--scene-points", "20000", "-o", out});
        ASSERT_EQ(r.exitCode, 0) << r.output;
    }
    // A staged build into the set, up to its merge.
    auto r = test::run({build, "plan", "-q", "--work", work, "--default-scene", "--scene-points", "30000", "-o", set});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    ASSERT_EQ(test::run({build, "distribute", "-q", "--work", work}).exitCode, 0);
    const size_t chunks = nlohmann::json::parse(test::readFile(work + "/plan.json"))["chunks"].get<size_t>();
    for (size_t i = 0; i < chunks; ++i) ASSERT_EQ(test::run({build, "chunk", "-q", "--work", work, std::to_string(i)}).exitCode, 0);
    test::writeFile(dir.file("added.xyz"), "0 0 0\n0.1 0 0\n0 0.1 0\n");
    const std::map<std::string, std::string> before = setFiles(set);

    const int held = ::open(set.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    ASSERT_GE(held, 0);
    ASSERT_EQ(::flock(held, LOCK_EX | LOCK_NB), 0);
    const std::vector<std::vector<std::string>> writers = {
        {build, "-q", "--default-scene", "--scene-points", "30000", "-o", set},
        {build, "-q", "--merge", other, set, "-o", set},
        {build, "merge", "-q", "--work", work},
        {build, "-q", "--add", dir.file("added.xyz"), "--to", set},
        {build, "-q", "--compact", set},
    };
    for (const auto& args : writers) {
        r = test::run(args);
        EXPECT_EQ(r.exitCode, 1) << args[1] << " " << args[2] << ": " << r.output;
        EXPECT_NE(r.output.find(set + ": another build, update or compaction of this set is running"), std::string::npos)
            << args[1] << " " << args[2] << ": " << r.output;
    }
    EXPECT_TRUE(setFiles(set) == before) << "a writer changed the set while another held its lock";
    ::close(held);

    // Once the lock is free, the rebuild writes the set.
    r = test::run({build, "-q", "--default-scene", "--scene-points", "30000", "-o", set});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_FALSE(setFiles(set) == before);
    r = test::run({build, "--info", set});
    EXPECT_EQ(r.exitCode, 0) << r.output;
}

// An update writes the version of the set it read at its start or nothing.
// The update's own steps (those updateTileset takes: the set read, its
// writer made, then finish) with a rebuild of the set in between, which no
// lock stopped (a writer that takes none: the lock is advisory): finish
// fails, naming the set, and the rebuilt set stays whole, byte for byte.
TEST(Cli, AnUpdateWhoseSetWasReplacedUnderItFailsAndLeavesTheNewerSet) {
    test::TempDir dir;
    const std::string set = dir.file("s");
    const std::string build = test::binary("surfcast-build");
    auto r = test::run({build, "-q", "--default-scene", "--scene-points", "20000", "-o", set});
    ASSERT_EQ(r.exitCode, 0) << r.output;

    auto reader = TilesetReader::open(set);
    ASSERT_TRUE(reader) << reader.status().message();
    auto writer = TilesetWriter::update(set, reader->info(), reader->nodes(), [&](const std::vector<NodeRecord>& n) { return reader->readBlocksBytes(n); });
    ASSERT_TRUE(writer) << writer.status().message();
    // Every node kept but the root, whose blob comes again, one byte changed
    // (so that it is appended).
    std::vector<NodeRecord> kept;
    const NodeRecord* root = nullptr;
    for (const NodeRecord& n : reader->nodes())
        if (n.key == NodeKey{}) root = &n;
        else kept.push_back(n);
    ASSERT_TRUE(root);
    ASSERT_TRUE((*writer)->addKeptNodes(kept).ok());
    const std::string blocks = test::readFile(set + "/blocks.bin");
    std::vector<uint8_t> blob(blocks.begin() + long(root->blockOffset), blocks.begin() + long(root->blockOffset + root->blockSize));
    blob.back() ^= 1;
    ASSERT_TRUE((*writer)->addNode(*root, blob).ok());

    r = test::run({build, "-q", "--default-scene", "--scene-points", "30000", "-o", set});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const std::map<std::string, std::string> rebuilt = setFiles(set);

    TilesetInfo info = reader->info();
    const Status finished = (*writer)->finish(info);
    ASSERT_FALSE(finished.ok()) << "the update wrote over a set it did not read";
    EXPECT_NE(finished.message().find(set + ": changed since this update read it"), std::string::npos) << finished.message();
    writer->reset();  // (its hidden folder gone, as when an update ends)
    EXPECT_TRUE(setFiles(set) == rebuilt) << "the update changed the set that replaced the one it read";
    r = test::run({build, "--info", set});
    EXPECT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("checksums verified"), std::string::npos) << r.output;
}
