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
#include <functional>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include <nlohmann/json.hpp>

#include "block_codec.h"
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
inline void leafPoints(const std::string& set, double* largestStep, std::vector<Point>* points) {
    auto reader = TilesetReader::open(set);
    ASSERT_TRUE(reader) << reader.status().message();
    std::vector<Point>& out = *points;
    for (const NodeRecord& n : reader->nodes()) {
        if (!(n.flags & kFlagInputPoints)) continue;
        auto bytes = reader->readBlockBytes(n);
        ASSERT_TRUE(bytes) << bytes.status().message();
        BlockExpectation expect = reader->expectation(n);
        expect.scalars = true;
        auto block = decodeBlock(bytes->data(), bytes->size(), expect);
        EXPECT_TRUE(block) << block.status().message();
        if (!block) continue;
        const ScalarAttribute* input = nullptr;
        for (const ScalarAttribute& a : block->scalars)
            if (a.name == "input") input = &a;
        *largestStep = std::max(*largestStep, positionStep(reader->info(), n));
        for (size_t i = 0; i < block->size(); ++i) {
            Point q;
            q.p = reader->position(n, *block, i);
            // As read, not as stored: sets of other inputs quantize it from another minimum.
            // Each where the set stores it (the lion has no classes or returns).
            if (const AttributeInfo* intensity = reader->info().attribute("intensity"))
                q.intensity = uint16_t(std::lround(block->intensity.at(i) * intensity->scale + intensity->offset));
            if (!block->classification.empty()) q.classification = block->classification.at(i);
            if (!block->returnNumber.empty()) q.returnNumber = block->returnNumber.at(i);
            if (!block->numberOfReturns.empty()) q.returns = block->numberOfReturns.at(i);
            if (!block->colors.empty())
                for (int c = 0; c < 3; ++c) q.color[c] = block->colors.at(3 * i + c);
            if (input) q.input = int(input->values.at(i));
            out.push_back(q);
        }
    }
}

// How many of `want` have a point of `have` within `tolerance` (each used
// once) with the same attributes and input: a maximum matching (nearest pairs first,
// then augmenting paths), as points quantized onto a coarse lattice leave
// several candidates each.
inline size_t matchPoints(const std::vector<Point>& want, const std::vector<Point>& have, double tolerance) {
    const double cell = 4 * tolerance;
    auto cellOf = [&](const Vec3d& p) {
        return std::make_tuple(int64_t(std::floor(p.x / cell)), int64_t(std::floor(p.y / cell)), int64_t(std::floor(p.z / cell)));
    };
    std::map<std::tuple<int64_t, int64_t, int64_t>, std::vector<size_t>> grid;
    for (size_t i = 0; i < have.size(); ++i) grid[cellOf(have[i].p)].push_back(i);
    std::vector<std::tuple<double, size_t, size_t>> pairs;  // distance, want, have
    for (size_t j = 0; j < want.size(); ++j) {
        const Point& w = want[j];
        const auto [cx, cy, cz] = cellOf(w.p);
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz) {
                    auto it = grid.find({cx + dx, cy + dy, cz + dz});
                    if (it == grid.end()) continue;
                    for (size_t i : it->second) {
                        const Point& h = have[i];
                        const Vec3d d = h.p - w.p;
                        const double distance = std::max({std::fabs(d.x), std::fabs(d.y), std::fabs(d.z)});
                        if (distance > tolerance || h.input != w.input || h.intensity != w.intensity || h.classification != w.classification ||
                            h.returnNumber != w.returnNumber || h.returns != w.returns || h.color[0] != w.color[0] ||
                            h.color[1] != w.color[1] || h.color[2] != w.color[2])
                            continue;
                        pairs.push_back({distance, j, i});
                    }
                }
    }
    std::sort(pairs.begin(), pairs.end());
    std::vector<std::vector<size_t>> edges(want.size());
    std::vector<long> partnerOf(have.size(), -1), partner(want.size(), -1);
    size_t matched = 0;
    for (const auto& [distance, j, i] : pairs) {
        edges[j].push_back(i);
        if (partner[j] < 0 && partnerOf[i] < 0) partner[j] = long(i), partnerOf[i] = long(j), ++matched;
    }
    // Kuhn's augmenting paths from each point the greedy pass left alone.
    std::vector<size_t> seen(have.size(), SIZE_MAX);
    std::function<bool(size_t, size_t)> augment = [&](size_t j, size_t round) {
        for (size_t i : edges[j]) {
            if (seen[i] == round) continue;
            seen[i] = round;
            if (partnerOf[i] < 0 || augment(size_t(partnerOf[i]), round)) {
                partnerOf[i] = long(j), partner[j] = long(i);
                return true;
            }
        }
        return false;
    };
    for (size_t j = 0; j < want.size(); ++j)
        if (partner[j] < 0 && augment(j, j)) ++matched;
    return matched;
}

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
