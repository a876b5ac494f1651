// What update_test's cases share (update_test.cpp: updates in one process;
// update_test_stages.cpp: in stages, and --merge): the sets' leaf points and
// their matching, the update in stages, and the fixture whose base set of
// autzen's cells is built once for the program.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "test_support.h"
#include "tileset_reader.h"

namespace surfcast::update_test {

namespace fs = std::filesystem;

struct Point {
    Vec3d p;
    int input = -1;  // the provenance attribute's value, where the set has it
    uint16_t intensity = 0;
    uint8_t classification = 0, returnNumber = 0, returns = 0;
    uint16_t color[3] = {};
};

// Every leaf point of a set (world positions, stored attributes), and the
// largest quantization step of its leaves.
void leafPoints(const std::string& set, double* largestStep, std::vector<Point>* points);

// How many of `want` have a point of `have` within `tolerance` (each used
// once) with the same attributes and input: a maximum matching (nearest pairs first,
// then augmenting paths), as points quantized onto a coarse lattice leave
// several candidates each.
size_t matchPoints(const std::vector<Point>& want, const std::vector<Point>& have, double tolerance);

// `have` holds `want`'s points: the same count, each within 1.5 times the
// largest leaf step `step` (the bound AddedScanEqualsAFreshBuildAndKeepsTheOtherNodes
// derives), attributes and input exact.
inline void expectSamePoints(const std::vector<Point>& want, const std::vector<Point>& have, double step) {
    ASSERT_EQ(have.size(), want.size());
    EXPECT_EQ(matchPoints(want, have, 1.5 * step), want.size()) << "leaf step " << step;
}

// Every file of a folder, by name.
inline std::map<std::string, std::string> folderFiles(const std::string& dir) {
    std::map<std::string, std::string> files;
    for (const auto& e : fs::directory_iterator(dir)) files[e.path().filename().string()] = test::readFile(e.path().string());
    return files;
}

// `update` (--add ..., --remove ...) of `set` in stages (update.h):
// update-plan, chunk of the chunks plan.json names, update-merge.
inline void stagedUpdate(const std::string& set, const std::string& work, const std::vector<std::string>& update) {
    std::vector<std::string> plan = {test::binary("surfcast-build"), "update-plan", "-q", "--work", work};
    plan.insert(plan.end(), update.begin(), update.end());
    plan.insert(plan.end(), {"--to", set});
    auto r = test::run(plan);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::vector<std::string> chunk = {test::binary("surfcast-build"), "chunk", "-q", "--work", work};
    const nlohmann::json planned = nlohmann::json::parse(test::readFile(work + "/plan.json"));
    for (size_t i : planned["build"]) chunk.push_back(std::to_string(i));
    r = test::run(chunk);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    r = test::run({test::binary("surfcast-build"), "update-merge", "-q", "--work", work});
    ASSERT_EQ(r.exitCode, 0) << r.output;
}

inline std::vector<std::string> build(std::vector<std::string> args) {
    args.insert(args.begin(), {test::binary("surfcast-build"), "-q", "--memory", "64M", "--capacity", "1000"});
    return args;
}

// autzen_trim.las cut into 4 x 4 cells of files (tests/tools/split_laz.py);
// r000005.laz is an inner cell, so the others span the same bounds. The cells
// and the set of all but the inner one are made once for the program's cases
// (CI's time: bench/RELIABILITY.md, "CI stages"); each case updates its own
// copy of the set, and finds the cells at parts/ in its folder too.
class UpdateTest : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        base_.clear();
        added_.clear();
        sharedError_.clear();
        if (!fs::exists(SURFCAST_TEST_PYTHON)) return;  // SetUp says why
        if (!fs::exists(test::dataFile("autzen_trim.las"))) {
            sharedError_ = "missing " + test::dataFile("autzen_trim.las");
            return;
        }
        shared_ = new test::TempDir;
        auto split = test::run({SURFCAST_TEST_PYTHON, SURFCAST_TEST_TOOLS "/split_laz.py", test::dataFile("autzen_trim.las"),
                                shared_->file("parts"), "--cells", "4x4x1", "--min-files", "16"});
        if (split.exitCode != 0) {
            sharedError_ = "split_laz.py: " + split.output;
            return;
        }
        for (int i = 0; i < 16; ++i) {
            char name[32];
            std::snprintf(name, sizeof name, "/parts/r%06d.laz", i);
            (i == 5 ? added_ : base_).push_back(shared_->path() + name);
        }
        auto args = base_;
        args.insert(args.end(), {"-o", shared_->file("base-set")});
        auto built = test::run(build(args));
        if (built.exitCode != 0) sharedError_ = "the base set: " + built.output;
    }
    static void TearDownTestSuite() {
        delete shared_;
        shared_ = nullptr;
    }
    void SetUp() override {
        REQUIRE_DATA();
        REQUIRE_TEST_PYTHON();
        ASSERT_TRUE(shared_ && sharedError_.empty()) << sharedError_;
        base = base_;
        added = added_;
        fs::create_directory_symlink(shared_->file("parts"), dir.file("parts"));
        fs::create_directories(dir.file("sets"));
        fs::copy(shared_->file("base-set"), set(), fs::copy_options::recursive);
    }
    std::string set() const { return dir.file("sets/s"); }
    // The base set as built, which no case changes.
    static std::string shared() { return shared_->file("base-set"); }

    test::TempDir dir;
    std::vector<std::string> base, added;

private:
    static inline test::TempDir* shared_ = nullptr;
    static inline std::string sharedError_;
    static inline std::vector<std::string> base_, added_;
};

}  // namespace surfcast::update_test
