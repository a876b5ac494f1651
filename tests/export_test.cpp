// surfcast-export --format laz and copc: a set's input points back out, checked
// against the LAS file the set was built from by laspy (an independent
// reader: tests/tools/compare_las.py) and by the build's own LAS reader.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>

#include "gaussians.h"
#include "las_reader.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace fs = std::filesystem;
using namespace surfcast;

namespace {

// autzen_trim.las stores coordinates at 0.01 (its scale): a leaf keeps them
// within half of that (FORMAT.md: leaves use the input's own precision), and
// the export writes them on the input's own lattice, so they come back
// exactly; matching exported points to the original's within half a step
// finds each one all the same, and a box grown and shrunk by it brackets the
// points the export keeps.
constexpr double kPositionError = 0.005;

nlohmann::json compare(const std::string& original, const std::string& exported, const std::vector<std::string>& filter) {
    std::vector<std::string> args = {SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/compare_las.py", original, exported, "--tolerance",
                                     std::to_string(kPositionError)};
    args.insert(args.end(), filter.begin(), filter.end());
    auto r = test::run(args);
    EXPECT_EQ(r.exitCode, 0) << r.output;
    return r.exitCode == 0 ? nlohmann::json::parse(r.output) : nlohmann::json{};
}

uint64_t countWithOwnReader(const std::string& path) {
    auto r = openLasReader(path);
    EXPECT_TRUE(r.ok()) << r.status().message();
    if (!r.ok()) return 0;
    std::vector<InputPoint> batch(10000);
    uint64_t n = 0;
    while (true) {
        auto got = (*r)->read(batch.data(), batch.size());
        EXPECT_TRUE(got.ok()) << got.status().message();
        if (!got.ok() || *got == 0) break;
        n += *got;
    }
    return n;
}

class Export : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        if (!test::haveData() || !fs::exists(SURFCAST_TEST_PYTHON)) return;
        dir_ = new test::TempDir;
        auto b = test::run({test::binary("surfcast-build"), "-q", test::dataFile("autzen_trim.las"), "--attributes", "all", "-o",
                            dir_->file("autzen")});
        ASSERT_EQ(b.exitCode, 0) << b.output;
    }
    static void TearDownTestSuite() {
        delete dir_;
        dir_ = nullptr;
    }
    void SetUp() override {
        REQUIRE_DATA();
        REQUIRE_TEST_PYTHON();
        ASSERT_NE(dir_, nullptr);
    }
    static test::TempDir* dir_;
};
test::TempDir* Export::dir_ = nullptr;

// Every point, with every attribute the LAS file had and the set stores.
TEST_F(Export, WholeSetGivesBackItsInputPoints) {
    const std::string out = dir_->file("all.laz");
    auto e = test::run({test::binary("surfcast-export"), dir_->file("autzen"), "--format", "laz", "-o", out});
    ASSERT_EQ(e.exitCode, 0) << e.output;
    EXPECT_NE(e.output.find("wrote " + out + ": 110000 points"), std::string::npos) << e.output;
    const nlohmann::json c = compare(test::dataFile("autzen_trim.las"), out, {});
    EXPECT_EQ(c["exported"], 110000);  // PROVENANCE.md; no exact duplicates among them
    EXPECT_EQ(c["matched"], 110000);
    EXPECT_EQ(c["largest_error"].get<double>(), 0.0);
    EXPECT_EQ(c["point_format"], 3);  // the input's own
    // The header's bounds hold every point; for a whole set they come from
    // tileset.json grown by half the coarsest leaf step (0.005 here) and
    // rounded outward to the LAS scale (0.01): 0.01 of slack at most.
    EXPECT_TRUE(c["inside_header"].get<bool>());
    EXPECT_LE(c["header_slack"].get<double>(), 0.01 + 1e-9);
    for (const char* d : {"intensity", "classification", "return_number", "number_of_returns", "user_data", "red", "green", "blue"})
        EXPECT_EQ(c["same"][d], 110000) << d;
    // gps_time's values are multiples of a power of two that spans their
    // range in 32 bits: stored exactly. Scan angles in whole degrees, as they came.
    EXPECT_EQ(c["gps_time_error"].get<double>(), 0.0);
    EXPECT_EQ(c["scan_angle_error"].get<double>(), 0.0);
    // The chunk table's offset is at the file's end (the stream never seeks
    // back): the build's own reader finds it there too.
    EXPECT_EQ(countWithOwnReader(out), 110000u);
}

// A box and a class: the points of class 2 inside it, as laspy counts them
// in the original file.
TEST_F(Export, BoxAndClassesKeepWhatTheySay) {
    const std::string out = dir_->file("box.laz"), box = "636500,849000,0,637000,849400,1000";
    auto e = test::run({test::binary("surfcast-export"), "-q", dir_->file("autzen"), "--format", "laz", "--bbox", box, "--classes", "2",
                        "-o", out});
    ASSERT_EQ(e.exitCode, 0) << e.output;
    const nlohmann::json c = compare(test::dataFile("autzen_trim.las"), out, {"--box", box, "--classes", "2"});
    EXPECT_GT(c["exported"].get<int>(), 1000);
    EXPECT_LT(c["exported"].get<int>(), 110000 / 2);
    EXPECT_GE(c["exported"].get<int>(), c["kept_shrunk"].get<int>());
    EXPECT_LE(c["exported"].get<int>(), c["kept_grown"].get<int>());
    EXPECT_EQ(c["matched"], c["exported"]);
    EXPECT_EQ(c["classes"], nlohmann::json::array({2}));
    // A filtered export's header bounds are its points' own.
    EXPECT_TRUE(c["inside_header"].get<bool>());
    EXPECT_LE(c["header_slack"].get<double>(), 1e-9);
    // A box that holds no point: a valid file of none.
    const std::string empty = dir_->file("empty.laz");
    auto none = test::run({test::binary("surfcast-export"), "-q", dir_->file("autzen"), "--format", "laz", "--bbox", "0,0,0,1,1,1", "-o",
                           empty});
    ASSERT_EQ(none.exitCode, 0) << none.output;
    EXPECT_EQ(compare(test::dataFile("autzen_trim.las"), empty, {})["exported"], 0);
}

// COPC: laspy's COPC reader (its own parser of the info VLR, the hierarchy
// and the chunks) finds the points of the LAZ export, record for record; the
// root holds one point in each cell of its 128³ grid that the points occupy
// (counted by numpy: a point within half the LAS scale of a cell's face may
// fall on either side, so 0.5 % may differ), the levels add up to all, and a
// query by half the box returns the points there.
TEST_F(Export, CopcHoldsTheSamePointsInAnOctree) {
    const std::string laz = dir_->file("for-copc.laz"), copc = dir_->file("all.copc.laz");
    for (const auto& [format, out] : {std::pair<std::string, std::string>{"laz", laz}, {"copc", copc}}) {
        auto e = test::run({test::binary("surfcast-export"), "-q", dir_->file("autzen"), "--format", format, "-o", out});
        ASSERT_EQ(e.exitCode, 0) << e.output;
    }
    auto r = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/check_copc.py", copc, laz});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const nlohmann::json c = nlohmann::json::parse(r.output);
    EXPECT_EQ(c["laz"], 110000);
    EXPECT_EQ(c["query"], 110000);
    EXPECT_TRUE(c["same_records"].get<bool>());
    // Read as plain LAZ (its chunk table, its offset written over the -1):
    // by laspy and by the build's own reader.
    EXPECT_EQ(c["plain"], 110000);
    EXPECT_TRUE(c["plain_same_records"].get<bool>());
    EXPECT_EQ(countWithOwnReader(copc), 110000u);
    const auto levels = c["levels"].get<std::vector<int>>();
    ASSERT_GE(levels.size(), 3u);
    const int cells = c["root_cells"].get<int>();
    EXPECT_GT(cells, 1000);
    EXPECT_LE(std::abs(levels[0] - cells), cells / 200) << levels[0] << " points at the root";
    int sum = 0;
    for (int n : levels) sum += n;
    EXPECT_EQ(sum, 110000);
    EXPECT_EQ(c["half_query"], c["half_expected"]);
    EXPECT_GT(c["half_query"].get<int>(), 1000);
    // A box and classes: the same points as the LAZ export of them.
    const std::string box = "636500,849000,0,637000,849400,1000";
    for (const auto& [format, out] : {std::pair<std::string, std::string>{"laz", laz}, {"copc", copc}}) {
        auto e = test::run({test::binary("surfcast-export"), "-q", dir_->file("autzen"), "--format", format, "--bbox", box, "--classes", "2",
                            "-o", out});
        ASSERT_EQ(e.exitCode, 0) << e.output;
    }
    auto boxed = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/check_copc.py", copc, laz});
    ASSERT_EQ(boxed.exitCode, 0) << boxed.output;
    const nlohmann::json b = nlohmann::json::parse(boxed.output);
    EXPECT_GT(b["query"].get<int>(), 1000);
    EXPECT_TRUE(b["same_records"].get<bool>()) << boxed.output;
    EXPECT_TRUE(b["plain_same_records"].get<bool>()) << boxed.output;
    // A box that holds no point: a valid COPC file of none.
    for (const auto& [format, out] : {std::pair<std::string, std::string>{"laz", laz}, {"copc", copc}}) {
        auto e = test::run({test::binary("surfcast-export"), "-q", dir_->file("autzen"), "--format", format, "--bbox", "0,0,0,1,1,1", "-o", out});
        ASSERT_EQ(e.exitCode, 0) << e.output;
    }
    auto empty = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/check_copc.py", copc, laz});
    ASSERT_EQ(empty.exitCode, 0) << empty.output;
    EXPECT_EQ(nlohmann::json::parse(empty.output)["query"], 0);
    EXPECT_EQ(nlohmann::json::parse(empty.output)["plain"], 0);
}

// Wrong arguments and sets: a clear error, a non-zero exit, no file.
TEST_F(Export, BadArgumentsAndSetsAreClearErrors) {
    const std::string out = dir_->file("bad.laz");
    struct Case {
        std::vector<std::string> args;
        int exit;
        std::string message;
    };
    const Case cases[] = {
        {{dir_->file("autzen"), "--format", "laz", "--bbox", "1,2,3", "-o", out}, 2, "six numbers"},
        {{dir_->file("autzen"), "--format", "laz", "--bbox", "0,0,0,1,x,1", "-o", out}, 2, "'x' is not a number"},
        {{dir_->file("autzen"), "--format", "laz", "--bbox", "5,0,0,1,1,1", "-o", out}, 2, "minimum exceeds its maximum on axis x"},
        {{dir_->file("autzen"), "--format", "laz", "--classes", "2,300", "-o", out}, 2, "'300' is not a class"},
        {{dir_->file("autzen"), "--format", "las", "-o", out}, 2, "--format las: the formats are laz, copc, 3dtiles, ply and spz"},
        {{dir_->file("autzen"), "--format", "ply", "--level", "two", "-o", out}, 2, "--level wants a level"},
        {{dir_->file("autzen"), "--format", "spz", "--level", "2", "--splat-budget", "1000", "-o", out}, 2, "not both"},
        {{dir_->file("autzen"), "--format", "ply", "--as", "points", "-o", out}, 2, "--as is for --format 3dtiles"},
        {{dir_->file("autzen"), "--format", "laz", "--level", "2", "-o", out}, 2, "are for --format ply and spz"},
        {{dir_->file("autzen"), "--format", "3dtiles", "--camera", "0,0,0,1,1,1,0,0,1,45", "-o", out}, 2, "are for --format ply and spz"},
        {{dir_->file("autzen"), "--format", "ply", "--camera", "0,0,0", "-o", out}, 2, "--camera: "},
        {{dir_->file("autzen"), "--format", "ply", "--camera", "0,0,0,1,1,1,0,0,1,45", "--level", "1", "-o", out}, 2, "--level or --camera, not both"},
        {{dir_->file("autzen"), "--format", "ply", "--camera", "0,0,0,1,1,1,0,0,1,45", "--level", "leaves", "-o", out}, 2, "--level or --camera, not both"},
        {{dir_->file("autzen"), "--format", "ply", "--level", "leaves", "--splat-budget", "1000", "-o", out}, 2, "--level or --splat-budget, not both"},
        {{dir_->file("autzen"), "--format", "spz", "--size", "640x480", "-o", out}, 2, "--size and --lod are for --camera"},
        {{dir_->file("autzen"), "--format", "spz", "--camera", "0,0,0,1,1,1,0,0,1,45", "--size", "99999999999x1", "-o", out}, 2,
         "--size wants WxH"},
        {{dir_->file("autzen"), "--format", "spz", "--camera", "0,0,0,1,1,1,0,0,1,45", "--lod", "0", "-o", out}, 2, "--lod wants pixels"},
        {{dir_->file("autzen"), "--format", "3dtiles", "--splat-scale", "0", "-o", out}, 2, "--splat-scale wants a number in (0, 100]"},
        {{dir_->file("autzen"), "--format", "spz", "--bbox", "0,0,0,1,1,1", "-o", out}, 2, "exports the whole set"},
        {{dir_->file("autzen"), "--format", "3dtiles", "--classes", "2", "-o", out}, 2, "exports the whole set"},
        {{dir_->file("autzen"), "--format", "laz", "--splat-scale", "2", "-o", out}, 2, "are for splats"},
        {{dir_->file("autzen"), "--format", "3dtiles", "--as", "points", "--splat-opacity", "0.5", "-o", out}, 2, "are for splats"},
        {{dir_->file("autzen"), "--format", "3dtiles", "--compression", "draco", "-o", out}, 2, "--compression wants meshopt or none"},
        {{dir_->file("autzen"), "--format", "3dtiles", "--compression", "none", "-o", out}, 2, "--compression is for --format 3dtiles --as points"},
        {{dir_->file("autzen"), "--format", "3dtiles", "--tiling", "sparse", "-o", out}, 2, "--tiling wants auto, explicit or implicit"},
        {{dir_->file("autzen"), "--format", "laz", "--tiling", "implicit", "-o", out}, 2, "--tiling is for --format 3dtiles"},
        {{dir_->file("autzen"), "--format", "laz"}, 2, "-o FILE is required"},
        {{dir_->file("nothing"), "--format", "laz", "-o", out}, 1, dir_->file("nothing")},
    };
    for (const Case& c : cases) {
        std::vector<std::string> args = {test::binary("surfcast-export")};
        args.insert(args.end(), c.args.begin(), c.args.end());
        auto r = test::run(args);
        EXPECT_EQ(r.exitCode, c.exit) << r.output;
        EXPECT_NE(r.output.find(c.message), std::string::npos) << r.output;
        EXPECT_FALSE(fs::exists(out));
    }
    // Classes asked of a set that stores no classification.
    auto scene = test::buildScene(dir_->file("scene"), 20000);
    ASSERT_EQ(scene.exitCode, 0) << scene.output;
    auto r = test::run({test::binary("surfcast-export"), dir_->file("scene"), "--format", "laz", "--classes", "2", "-o", out});
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("stores no classification"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(out));
    for (const auto& entry : fs::directory_iterator(dir_->path()))
        EXPECT_EQ(entry.path().filename().string().find(".partial-"), std::string::npos) << entry.path();
}

// --format 3dtiles, ply and spz (their consumers check what they write:
// web/test/exports.test.mjs): a damaged block is an error naming its node,
// and the output is the one before, never a part; nothing but a previous
// export is replaced.
TEST_F(Export, ThreeDTilesFailWholeOnDamagedSets) {
    const std::string good = dir_->file("autzen3d");
    auto r = test::run({test::binary("surfcast-export"), dir_->file("autzen"), "--format", "3dtiles", "-q", "-o", good});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const std::string before = test::readFile(good + "/tileset.json");
    ASSERT_NE(before.find("\"REPLACE\""), std::string::npos);
    // A file of ours in the export: a replaced folder would lose it.
    test::writeFile(good + "/sentinel", "kept");

    // The set with one byte flipped in the middle of one node's block.
    const std::string damaged = dir_->file("damaged");
    fs::copy(dir_->file("autzen"), damaged, fs::copy_options::recursive);
    auto set = TilesetReader::open(damaged);
    ASSERT_TRUE(set.ok()) << set.status().message();
    const NodeRecord& victim = set->nodes().back();
    ASSERT_EQ(victim.childMask, 0) << "the splat files below hold the leaves: the victim must be one";
    {
        std::fstream f(damaged + "/blocks.bin", std::ios::in | std::ios::out | std::ios::binary);
        f.seekg(std::streamoff(victim.blockOffset + victim.blockSize / 2));
        const char byte = char(f.get() ^ 0x5A);
        f.seekp(std::streamoff(victim.blockOffset + victim.blockSize / 2));
        f.put(byte);
    }
    for (const std::string& out : {dir_->file("damaged3d"), good}) {
        r = test::run({test::binary("surfcast-export"), damaged, "--format", "3dtiles", "-q", "-o", out});
        EXPECT_EQ(r.exitCode, 1) << r.output;
        EXPECT_NE(r.output.find("node " + victim.key.name()), std::string::npos) << r.output;
    }
    EXPECT_FALSE(fs::exists(dir_->file("damaged3d")));
    for (const char* format : {"ply", "spz"}) {  // the splat files hold the leaves; the victim, the last node, is one
        const std::string file = dir_->file(std::string("damaged.") + format);
        r = test::run({test::binary("surfcast-export"), damaged, "--format", format, "-q", "-o", file});
        EXPECT_EQ(r.exitCode, 1) << r.output;
        EXPECT_NE(r.output.find("node " + victim.key.name()), std::string::npos) << r.output;
        EXPECT_FALSE(fs::exists(file));
    }
    EXPECT_EQ(test::readFile(good + "/tileset.json"), before) << "the previous export stays whole";
    EXPECT_EQ(test::readFile(good + "/sentinel"), "kept") << "the previous export stays in place";

    // A Surfcast set (it has a tileset.json too) is not an export to replace,
    // nor another tool's tileset; and surfcast-build does not replace an export.
    r = test::run({test::binary("surfcast-export"), damaged, "--format", "3dtiles", "-q", "-o", dir_->file("autzen")});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("is not a 3D Tiles export of surfcast-export"), std::string::npos) << r.output;
    EXPECT_TRUE(TilesetReader::open(dir_->file("autzen")).ok());
    fs::create_directories(dir_->file("other"));
    test::writeFile(dir_->file("other/tileset.json"), R"({"asset": {"version": "1.1", "generator": "another tool"}, "geometricError": 1})");
    r = test::run({test::binary("surfcast-export"), dir_->file("autzen"), "--format", "3dtiles", "-q", "-o", dir_->file("other")});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("is not a 3D Tiles export of surfcast-export"), std::string::npos) << r.output;
    r = test::run({test::binary("surfcast-build"), "-q", test::dataFile("autzen_trim.las"), "-o", good});
    EXPECT_NE(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("is not a tile set"), std::string::npos) << r.output;
    EXPECT_EQ(test::readFile(good + "/sentinel"), "kept");
    for (const auto& entry : fs::directory_iterator(dir_->path()))
        EXPECT_EQ(entry.path().filename().string().find(".partial-"), std::string::npos) << entry.path();
}

// --camera cuts a splat file as the client cuts a view: the file holds as
// many splats as surfcast-view --lod draws at the same camera, size, level
// of detail and budget (its last frame's count), and a budget takes the
// coarsest gaps first, so the budgeted view holds fewer, within the budget.
TEST_F(Export, SplatFileOfAViewHoldsWhatSurfcastViewDraws) {
    const std::string camera = "636300,848500,900,636590,849216,430,0,0,1,45";
    const auto plyCount = [](const std::string& path) {
        const std::string head = test::readFile(path).substr(0, 400);
        const size_t at = head.find("element vertex ");
        return at == std::string::npos ? uint64_t(0) : std::stoull(head.substr(at + 15));
    };
    const auto viewCount = [&](const std::vector<std::string>& extra) {
        std::vector<std::string> args = {test::binary("surfcast-view"), "--headless", dir_->file("autzen"), "--camera", camera, "--size",
                                         "640x480", "--out", dir_->file("view.png")};
        args.insert(args.end(), extra.begin(), extra.end());
        auto r = test::run(args);
        EXPECT_EQ(r.exitCode, 0) << r.output;
        const size_t at = r.output.rfind("\"splats\":");
        return at == std::string::npos ? uint64_t(0) : std::stoull(r.output.substr(at + 9));
    };
    uint64_t counts[2] = {};
    for (int budgeted = 0; budgeted < 2; ++budgeted) {
        std::vector<std::string> lod = {"--lod", "2"};
        if (budgeted) lod.insert(lod.end(), {"--splat-budget", "20000"});
        const std::string out = dir_->file(budgeted ? "view-budget.ply" : "view.ply");
        std::vector<std::string> args = {test::binary("surfcast-export"), dir_->file("autzen"), "--format", "ply", "--camera", camera, "--size",
                                         "640x480", "-q", "-o", out};
        args.insert(args.end(), lod.begin(), lod.end());
        auto r = test::run(args);
        ASSERT_EQ(r.exitCode, 0) << r.output;
        counts[budgeted] = plyCount(out);
        EXPECT_EQ(counts[budgeted], viewCount(lod)) << (budgeted ? "with a budget" : "without a budget");
    }
    EXPECT_GT(counts[0], 20000u) << "the view without a budget needs more than the budget";
    EXPECT_LE(counts[1], 20000u);
    EXPECT_GT(counts[1], 0u);
}

// A node with more than 16 position bits (a float32 PLY's precision over
// a kilometre: about 24 bits at one node) keeps its positions as float
// offsets from its corner, not the block's integers, which
// KHR_mesh_quantization's 16 bits cannot hold. Read back by hand from the
// uncompressed export: every point where the set has it, to float rounding.
TEST(Tiles3d, PointsBeyondSixteenBitsAreFloatOffsets) {
    test::TempDir dir;
    std::string ply = "ply\nformat ascii 1.0\nelement vertex 400\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    for (int i = 0; i < 400; ++i)  // a jittered 20 x 20 grid over 1 km, gently sloped
        ply += std::to_string(1000.0 + (i % 20) * 50.0 + (i * 7919 % 13) * 0.37) + " " +
               std::to_string(2000.0 + (i / 20) * 50.0 + (i * 104729 % 11) * 0.41) + " " + std::to_string(30.0 + (i % 20) * 0.5) + "\n";
    test::writeFile(dir.file("km.ply"), ply);
    auto r = test::run({test::binary("surfcast-build"), "-q", dir.file("km.ply"), "-o", dir.file("km")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    r = test::run({test::binary("surfcast-export"), dir.file("km"), "--format", "3dtiles", "--as", "points", "--compression", "none", "-q",
                   "-o", dir.file("km3d")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto set = TilesetReader::open(dir.file("km"));
    ASSERT_TRUE(set.ok()) << set.status().message();
    const auto tileset = nlohmann::json::parse(test::readFile(dir.file("km3d/tileset.json")));
    const auto& t = tileset["root"]["transform"];
    const Vec3d origin{t[12].get<double>(), t[13].get<double>(), t[14].get<double>()};
    int wide = 0;
    for (const NodeRecord& node : set->nodes()) {
        if (node.positionBits <= 16 || node.surfelCount == 0) continue;
        ++wide;
        auto block = set->readBlock(node);
        ASSERT_TRUE(block.ok()) << block.status().message();
        const std::string glb = test::readFile(dir.file("km3d/tiles/" + node.key.name() + ".glb"));
        ASSERT_GE(glb.size(), 28u);
        uint32_t jsonLength = 0;
        std::memcpy(&jsonLength, glb.data() + 12, 4);
        const auto gltf = nlohmann::json::parse(glb.substr(20, jsonLength));
        const char* bin = glb.data() + 28 + jsonLength;
        const auto& accessor = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"].get<int>()];
        ASSERT_EQ(accessor["componentType"], 5126) << node.key.name() << ": " << int(node.positionBits) << " bits, float positions";
        ASSERT_EQ(accessor["count"], node.surfelCount);
        const auto& view = gltf["bufferViews"][accessor["bufferView"].get<int>()];
        ASSERT_EQ(view["byteStride"], 12);
        const auto& m = gltf["nodes"][0]["matrix"];
        const double edge = nodeEdge(set->info(), node.key.level);
        for (size_t i = 0; i < node.surfelCount; ++i) {
            float p[3];
            std::memcpy(p, bin + view["byteOffset"].get<size_t>() + 12 * i, 12);
            double q[3];  // glTF's y-up coordinates, less the root's translation
            for (int row = 0; row < 3; ++row)
                q[row] = m[row].get<double>() * p[0] + m[4 + row].get<double>() * p[1] + m[8 + row].get<double>() * p[2] + m[12 + row].get<double>();
            const Vec3d world = origin + Vec3d{q[0], -q[2], q[1]};
            const Vec3d want = set->position(node, *block, i);
            for (int a = 0; a < 3; ++a)  // a float offset of at most the node's edge: 2^-24 of it, and the double sums
                ASSERT_NEAR(world[a], want[a], edge * 1e-7) << node.key.name() << " point " << i << " axis " << a;
        }
    }
    EXPECT_GT(wide, 0) << "no node of the set has more than 16 position bits";
}

// A block's floats are not range-checked when decoded, so a hostile one
// with a valid CRC can hand the SPZ writer NaN or infinite values: an error,
// never undefined behaviour (UBSan runs this in the sanitizer stage).
TEST(Gaussians, SpzRefusesValuesThatAreNotFinite) {
    const Gaussian good{{1, 2, 3}, {0, 0, 1}, 0.5f, 0.01f, 1.f, {0.5f, 0.5f, 0.5f}};
    SpzWriter ok(10);
    ok.add(good);
    ASSERT_TRUE(ok.finish().ok());
    const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
    Gaussian bad[5] = {good, good, good, good, good};
    bad[0].sigma = nan;
    bad[1].normal = {nan, 0, 1};
    bad[2].opacity = inf;
    bad[3].color = {0, nan, 0};
    bad[4].position = {nan, 0, 0};
    for (const Gaussian& g : bad) {
        SpzWriter w(10);
        w.add(good);
        w.add(g);
        auto r = w.finish();
        ASSERT_FALSE(r.ok());
        EXPECT_NE(r.status().message().find(&g == &bad[4] ? "beyond the extent" : "not a finite number"), std::string::npos)
            << r.status().message();
    }
    // The extent sizes the fixed point: an extent of 1 leaves 22 fraction
    // bits, so 1.9 fits in 24 signed bits (2^23 - 1 steps) and 2.1 does not.
    for (const auto& [x, fits] : {std::pair{1.9f, true}, std::pair{2.1f, false}}) {
        SpzWriter w(1);
        w.add(Gaussian{{x, 0, 0}, {0, 0, 1}, 0.5f, 0.01f, 1.f, {0.5f, 0.5f, 0.5f}});
        EXPECT_EQ(w.finish().ok(), fits) << x;
    }
}

}  // namespace
