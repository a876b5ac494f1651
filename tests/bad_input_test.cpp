// Bad input through the real program: each case ends in a valid tile set or in
// a clear error naming the file and place, a non-zero exit and no output.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fcntl.h>

#include <chrono>
#include <cstring>
#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <thread>

#include "test_support.h"
#include "tileset_reader.h"

namespace fs = std::filesystem;
using namespace surfcast;
using test::TempDir;

namespace {

test::RunResult build(const TempDir& dir, const std::string& input, const std::vector<std::string>& extra = {}) {
    std::vector<std::string> args = {test::binary("surfcast-build"), "-q", input, "-o", dir.file("out")};
    args.insert(args.end(), extra.begin(), extra.end());
    return test::run(args);
}

// Nothing in the folder but the input files: no output, no leftovers.
void expectNoOutput(const TempDir& dir) {
    EXPECT_FALSE(fs::exists(dir.file("out")));
    for (const auto& e : fs::directory_iterator(dir.path()))
        EXPECT_EQ(e.path().filename().string().find(".out"), std::string::npos) << "leftover " << e.path();
}

void expectError(const TempDir& dir, const test::RunResult& r, const std::string& file, const std::string& place) {
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find(file), std::string::npos) << r.output;
    EXPECT_NE(r.output.find(place), std::string::npos) << r.output;
    expectNoOutput(dir);
}

std::string asciiPly(const std::vector<std::string>& rows) {
    std::string s = "ply\nformat ascii 1.0\nelement vertex " + std::to_string(rows.size()) +
                    "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    for (const auto& r : rows) s += r + "\n";
    return s;
}

uint64_t surfelsOf(const std::string& set) {
    auto r = TilesetReader::open(set);
    EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.status().message());
    return r.ok() ? r->info().surfels : 0;
}

}  // namespace

TEST(BadInput, TruncatedBinaryPly) {
    TempDir dir;
    std::string s = "ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n";
    s += std::string(12 * 500, '\0');
    test::writeFile(dir.file("t.ply"), s);
    expectError(dir, build(dir, dir.file("t.ply")), "t.ply", "1000 vertices");
}

TEST(BadInput, TruncatedAsciiPly) {
    TempDir dir;
    std::string s = asciiPly({"0 0 0", "1 1 1", "2 2 2"});
    s.resize(s.size() - 6);  // the last row is cut
    test::writeFile(dir.file("t.ply"), s);
    expectError(dir, build(dir, dir.file("t.ply")), "t.ply", "line");
}

TEST(BadInput, UnknownPropertyType) {
    TempDir dir;
    test::writeFile(dir.file("u.ply"), "ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n1\n");
    expectError(dir, build(dir, dir.file("u.ply")), "u.ply", "unknown property type 'float128'");
}

TEST(BadInput, PlyListWhereAScalarIsExpected) {
    // An intensity written as a list property: a clear error naming the file
    // and the property, never a misread of the following vertices.
    TempDir dir;
    test::writeFile(dir.file("l.ply"), "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                                       "property float z\nproperty list uchar float intensity\nend_header\n0 0 0 2 7 8\n");
    expectError(dir, build(dir, dir.file("l.ply")), "l.ply", "list property 'intensity'");
}

TEST(BadInput, MalformedHeaders) {
    TempDir dir;
    test::writeFile(dir.file("h.ply"), "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n");
    expectError(dir, build(dir, dir.file("h.ply")), "h.ply", "end_header");
    test::writeFile(dir.file("n.ply"), "plx\n");
    expectError(dir, build(dir, dir.file("n.ply")), "n.ply", "byte 0");
    test::writeFile(dir.file("l.las"), "LASF" + std::string(100, '\0'));
    expectError(dir, build(dir, dir.file("l.las")), "l.las", "227 bytes");
}

TEST(BadInput, EmptyFile) {
    TempDir dir;
    test::writeFile(dir.file("e.xyz"), "");
    expectError(dir, build(dir, dir.file("e.xyz")), "e.xyz", "empty");
}

TEST(BadInput, OnlyNaNPoints) {
    TempDir dir;
    test::writeFile(dir.file("nan.ply"), asciiPly({"nan 0 0", "0 inf 0"}));
    auto r = build(dir, dir.file("nan.ply"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("2 skipped"), std::string::npos) << r.output;
    expectNoOutput(dir);
}

TEST(BadInput, NaNPointsAreSkippedAndCounted) {
    TempDir dir;
    test::writeFile(dir.file("p.ply"), asciiPly({"0 0 0", "nan 1 1", "1 0 0", "0 1 0", "0 0 -inf", "1 1 0"}));
    auto r = build(dir, dir.file("p.ply"));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("points in: 4 (2 skipped"), std::string::npos) << r.output;
    EXPECT_EQ(surfelsOf(dir.file("out")), 4u);
}

TEST(BadInput, DegenerateGeometriesBuild) {
    struct Case { const char* name; std::vector<std::string> rows; uint64_t surfels; };
    std::vector<Case> cases = {
        {"single", {"5 6 7"}, 1},
        {"identical", std::vector<std::string>(50000, "1.5 -2 3"), 1},
    };
    std::vector<std::string> line, plane;
    for (int i = 0; i < 30000; ++i) line.push_back(std::to_string(i * 0.001) + " 0 0");
    for (int i = 0; i < 200; ++i)
        for (int j = 0; j < 150; ++j) plane.push_back(std::to_string(i * 0.01) + " " + std::to_string(j * 0.01) + " 2");
    cases.push_back({"collinear", line, 0});
    cases.push_back({"coplanar", plane, 0});
    for (const auto& c : cases) {
        TempDir dir;
        test::writeFile(dir.file("in.ply"), asciiPly(c.rows));
        auto r = build(dir, dir.file("in.ply"), {"--capacity", "5000"});
        ASSERT_EQ(r.exitCode, 0) << c.name << ": " << r.output;
        auto v = test::run({test::binary("surfcast-build"), "--info", dir.file("out")});
        EXPECT_EQ(v.exitCode, 0) << c.name << ": " << v.output;
        if (c.surfels) EXPECT_EQ(surfelsOf(dir.file("out")), c.surfels) << c.name;
        else EXPECT_GT(surfelsOf(dir.file("out")), c.rows.size()) << c.name;  // several levels
    }
}

// A million copies of one point (a scanner left standing, a duplicated
// tile) build: a neighbour search that ranked every copy against every
// other (10^12 distances, hours) would never finish, and ctest's timeout is
// what fails here then.
TEST(BadInput, AMillionCoincidentPointsBuild) {
    TempDir dir;
    test::writeFile(dir.file("in.ply"), asciiPly(std::vector<std::string>(1000000, "1.5 -2 3")));
    auto r = build(dir, dir.file("in.ply"), {});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("points in: 1000000 "), std::string::npos) << r.output;
    EXPECT_EQ(surfelsOf(dir.file("out")), 1u);
}

TEST(BadInput, LasCountMismatch) {
    TempDir dir;
    std::string h(227, '\0');
    std::memcpy(h.data(), "LASF", 4);
    h[24] = 1;
    h[25] = 2;
    uint16_t hs = 227;
    uint32_t off = 227, count = 10;
    std::memcpy(h.data() + 94, &hs, 2);
    std::memcpy(h.data() + 96, &off, 4);
    uint16_t len = 20;
    std::memcpy(h.data() + 105, &len, 2);
    std::memcpy(h.data() + 107, &count, 4);
    double scale = 0.01;
    for (int a = 0; a < 3; ++a) std::memcpy(h.data() + 131 + 8 * a, &scale, 8);
    test::writeFile(dir.file("c.las"), h + std::string(20 * 7, '\0'));
    expectError(dir, build(dir, dir.file("c.las")), "c.las", "declares 10 points, the file holds 7");
}

TEST(BadInput, UnknownFormatAndMissingFile) {
    TempDir dir;
    test::writeFile(dir.file("x.foo"), "hello");
    expectError(dir, build(dir, dir.file("x.foo")), "x.foo", "unknown input format");
    expectError(dir, build(dir, dir.file("missing.ply")), "missing.ply", "no such file");
}

TEST(BadInput, KilledBuildLeavesNoTileset) {
    TempDir dir;
    pid_t pid = fork();
    if (pid == 0) {
        int devnull = open("/dev/null", O_WRONLY);
        dup2(devnull, 2);
        dup2(devnull, 1);
        std::string bin = test::binary("surfcast-build"), out = dir.file("out");
        execl(bin.c_str(), bin.c_str(), "--default-scene", "--scene-points", "300000", "-o", out.c_str(), nullptr);
        _exit(127);
    }
    // Killed while it writes blocks (the first has reached the chunk's block
    // file, written as nodes/0.blocks.partial-HOST-PID in the work folder
    // beside the partial one: one chunk here), however fast or slow the
    // machine: event-driven, with a generous bound for sanitizer builds.
    const std::string nodes = dir.file(".out.partial-" + std::to_string(pid) + "-work/nodes");
    auto writingBlocks = [&] {
        std::error_code ec;
        for (const auto& e : fs::directory_iterator(nodes, ec))
            if (e.path().filename().string().rfind("0.blocks.partial-", 0) == 0 && fs::file_size(e.path(), ec) > 0 && !ec) return true;
        return false;
    };
    for (int i = 0; i < 12000 && !writingBlocks(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    const bool writing = writingBlocks();
    kill(pid, SIGKILL);
    int status = 0;
    waitpid(pid, &status, 0);
    ASSERT_TRUE(writing) << "no block written within 60 s";
    ASSERT_TRUE(WIFSIGNALED(status)) << "the build finished before it could be killed";
    EXPECT_FALSE(fs::exists(dir.file("out")));
    for (const auto& e : fs::recursive_directory_iterator(dir.path()))
        EXPECT_NE(e.path().filename(), "tileset.json") << e.path();
}

// A tile set's three files (all empty when there is no tileset.json).
struct SetFiles {
    std::string json, hierarchy, blocks;
    bool operator==(const SetFiles&) const = default;
    bool empty() const { return json.empty(); }
};
SetFiles readSet(const std::string& dir) {
    if (!fs::exists(dir + "/tileset.json")) return {};
    return {test::readFile(dir + "/tileset.json"), test::readFile(dir + "/hierarchy.bin"),
            test::readFile(dir + "/blocks.bin")};
}
void writeSet(const std::string& dir, const SetFiles& set) {
    fs::create_directories(dir);
    test::writeFile(dir + "/hierarchy.bin", set.hierarchy);
    test::writeFile(dir + "/blocks.bin", set.blocks);
    test::writeFile(dir + "/tileset.json", set.json);
}

// Runs `args` and SIGKILLs it after `seconds` (if it is still running);
// whether it was killed.
bool runAndKill(const std::vector<std::string>& args, double seconds) {
    pid_t pid = fork();
    if (pid == 0) {
        int devnull = open("/dev/null", O_WRONLY);
        dup2(devnull, 2);
        dup2(devnull, 1);
        std::vector<char*> argv;
        for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        execv(argv[0], argv.data());
        _exit(127);
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    int status = 0;
    while (waitpid(pid, &status, WNOHANG) == 0) {
        if (std::chrono::steady_clock::now() >= deadline) {
            kill(pid, SIGKILL);
            waitpid(pid, &status, 0);
            return WIFSIGNALED(status);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << args[0] << " failed on its own";
    return false;
}

TEST(BadInput, KillAnywhereLeavesTheOldSetOrTheNewOne) {
    // surfcast-build (set A replaced by set B) and surfcast-weights (A
    // re-weighted in place into W), each SIGKILLed at 20 moments (6 under a
    // sanitizer, where every run is several times longer) drawn
    // uniformly over its whole run. After every kill the output holds A byte
    // for byte, or the finished result byte for byte, or nothing that reads
    // as a tile set. The builds are deterministic, so the finished results
    // are known from one run each. Afterwards one more build leaves no hidden
    // folder behind: it removed what the killed runs left.
    TempDir dir;
    const std::string out = dir.file("out"), bin = test::binary("surfcast-build");
    const std::vector<std::string> buildA = {bin, "-q", "--default-scene", "--scene-points", "60000", "-o", out};
    const std::vector<std::string> buildB = {bin, "-q", "--default-scene", "--scene-points", "45000", "-o", out};
    const std::vector<std::string> reweight = {test::binary("surfcast-weights"), out, "--method", "capture", "--views", "4",
                                               "--size", "128"};
    auto timed = [](const std::vector<std::string>& args) {
        auto t0 = std::chrono::steady_clock::now();
        auto r = test::run(args);
        EXPECT_EQ(r.exitCode, 0) << r.output;
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    };
    timed(buildB);
    const SetFiles setB = readSet(out);
    timed(buildA);
    const SetFiles setA = readSet(out);
    const double weighSeconds = timed(reweight);
    const SetFiles setW = readSet(out);
    timed(buildA);
    const double buildSeconds = timed(buildB);
    ASSERT_FALSE(setA.empty() || setB.empty() || setW.empty());
    ASSERT_TRUE(setA != setB && setA != setW);
    ASSERT_TRUE(readSet(out) == setB) << "surfcast-build is not deterministic: the check below needs it to be";

    std::mt19937 random(15);
    int killed = 0;
    std::map<std::string, int> outcomes;
    const int runs = test::kSanitized ? 12 : 40;
    for (int i = 0; i < runs; ++i) {
        const bool weights = i % 2 == 1;
        // Start from A, whole (the previous kill may have left B, W or nothing).
        if (readSet(out) != setA) writeSet(out, setA);
        const double at = std::uniform_real_distribution<double>(0, 1.1 * (weights ? weighSeconds : buildSeconds))(random);
        killed += runAndKill(weights ? reweight : buildB, at);
        const SetFiles now = readSet(out);
        const SetFiles& finished = weights ? setW : setB;
        const char* outcome = now == setA ? "old" : now == finished ? "new" : "none";
        ++outcomes[std::string(weights ? "weights " : "build ") + outcome];
        if (now == setA || now == finished) continue;
        EXPECT_FALSE(TilesetReader::open(out)) << (weights ? "surfcast-weights" : "surfcast-build") << " killed after "
                                               << at << " s left a tile set that is neither the old one nor the new one";
    }
    for (const auto& [what, n] : outcomes) std::printf("%s: %d\n", what.c_str(), n);
    EXPECT_GE(killed, runs / 2) << "most runs should be killed before they finish";

    timed(buildB);
    EXPECT_TRUE(readSet(out) == setB);
    for (const auto& e : fs::directory_iterator(dir.path()))
        EXPECT_EQ(e.path().filename(), "out") << "left behind: " << e.path();
}

TEST(BadInput, BadFileAmongManyIsNamed) {
    // Many inputs are opened and decoded ahead, on other threads: an error
    // there still names the file and stops the build with nothing written.
    REQUIRE_DATA();
    TempDir dir;
    fs::create_directories(dir.file("in"));
    std::string laz = test::readFile(test::dataFile("Megaplot.laz"));
    for (int i = 0; i < 6; ++i) test::writeFile(dir.file("in/m" + std::to_string(i) + ".laz"), laz);
    test::writeFile(dir.file("in/m3.laz"), laz.substr(0, laz.size() / 2));  // truncated: no chunk table
    auto r = build(dir, dir.file("in"));
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("m3.laz"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("chunk table"), std::string::npos) << r.output;
    EXPECT_EQ(r.output.find("m4.laz"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(dir.file("out")));
    // The same files without the bad one build, every point counted.
    fs::remove(dir.file("in/m3.laz"));
    auto ok = build(dir, dir.file("in"));
    ASSERT_EQ(ok.exitCode, 0) << ok.output;
    EXPECT_NE(ok.output.find("points in: " + std::to_string(5 * 81590) + " "), std::string::npos) << ok.output;
}
