#include "cell_grid.h"

#include <algorithm>
#include <cmath>

namespace surfcast {

CellGrid::CellGrid(std::span<const Vec3f> points, float cell) : cell_(cell) {
    lo_ = points.empty() ? Vec3f{} : points[0];
    for (const Vec3f& p : points)
        for (int a = 0; a < 3; ++a) lo_[a] = std::min(lo_[a], p[a]);
    std::vector<std::pair<uint64_t, uint32_t>> keyed(points.size());
    for (size_t i = 0; i < points.size(); ++i) keyed[i] = {keyOf(coords(points[i])), uint32_t(i)};
    std::sort(keyed.begin(), keyed.end());
    order_.resize(points.size());
    for (size_t i = 0; i < keyed.size(); ++i) {
        order_[i] = keyed[i].second;
        if (i == 0 || keyed[i].first != keyed[i - 1].first) {
            keys_.push_back(keyed[i].first);
            begin_.push_back(uint32_t(i));
        }
    }
    begin_.push_back(uint32_t(keyed.size()));
}

std::array<int64_t, 3> CellGrid::coords(const Vec3f& p) const {
    std::array<int64_t, 3> c;
    // Points beyond 2^21 cells share the border cell: more candidates, none missed.
    for (int a = 0; a < 3; ++a) c[a] = std::clamp(int64_t(std::floor((p[a] - lo_[a]) / cell_)), int64_t(0), kAxisMax);
    return c;
}

void CellGrid::near(size_t cell, int64_t ring, std::vector<std::pair<uint32_t, uint32_t>>* runs) const {
    runs->clear();
    const uint64_t key = keys_[cell];
    const int64_t c[3] = {int64_t(key >> 42), int64_t(key >> 21 & kAxisMax), int64_t(key & kAxisMax)};
    for (int64_t x = std::max<int64_t>(c[0] - ring, 0); x <= std::min(c[0] + ring, kAxisMax); ++x)
        for (int64_t y = std::max<int64_t>(c[1] - ring, 0); y <= std::min(c[1] + ring, kAxisMax); ++y) {
            uint64_t first = keyOf({x, y, std::max<int64_t>(c[2] - ring, 0)});
            uint64_t last = keyOf({x, y, std::min(c[2] + ring, kAxisMax)});
            size_t i = size_t(std::lower_bound(keys_.begin(), keys_.end(), first) - keys_.begin()), j = i;
            while (j < keys_.size() && keys_[j] <= last) ++j;
            if (j > i) runs->push_back({begin_[i], begin_[j]});  // the column's cells are adjacent in order
        }
}

}  // namespace surfcast
