// A uniform grid over a point set, for neighbour searches on surface samples:
// the points sorted by cell, and the occupied cells' keys in order. Keys put z
// in the low bits, so the cells of one (x, y) column around a cell are one
// range of keys, found by one binary search.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "vec3.h"

namespace surfcast {

class CellGrid {
public:
    CellGrid(std::span<const Vec3f> points, float cell);

    size_t cells() const { return keys_.size(); }
    // The points in cell order: sorted position s holds point order()[s].
    const std::vector<uint32_t>& order() const { return order_; }
    // Sorted positions [begin, end) of a cell's points.
    uint32_t begin(size_t cell) const { return begin_[cell]; }
    uint32_t end(size_t cell) const { return begin_[cell + 1]; }
    // The runs [first, last) of sorted positions of the points in the cells
    // within `ring` cells of `cell`: every point within ring cell sizes of the
    // cell's points, and some farther.
    void near(size_t cell, int64_t ring, std::vector<std::pair<uint32_t, uint32_t>>* runs) const;

private:
    static constexpr int64_t kAxisMax = (int64_t(1) << 21) - 1;  // three 21-bit coordinates in a key
    std::array<int64_t, 3> coords(const Vec3f& p) const;
    static uint64_t keyOf(const std::array<int64_t, 3>& c) { return uint64_t(c[0]) << 42 | uint64_t(c[1]) << 21 | uint64_t(c[2]); }

    float cell_;
    Vec3f lo_;
    std::vector<uint32_t> order_;
    std::vector<uint64_t> keys_;
    std::vector<uint32_t> begin_;  // per cell, into order_; one more at the end
};

}  // namespace surfcast
