// update_support.h's leaf decoding and point matching, compiled once at the
// libraries' optimization: they loop over every leaf point of a set (over
// std::map in the matching), which the test files' -O0 under a sanitizer made
// the program's slowest part (bench/RELIABILITY.md, "CI stages").
#include "update_support.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <tuple>

#include "block_codec.h"

namespace surfcast::update_test {

void leafPoints(const std::string& set, double* largestStep, std::vector<Point>* points) {
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

size_t matchPoints(const std::vector<Point>& want, const std::vector<Point>& have, double tolerance) {
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

}  // namespace surfcast::update_test
