// Grid resampling: one level of the LDC-style octree (DESIGN.md decision 2).
// At most one surfel per occupied cell of a regular grid: its position is the
// input point nearest the cell's centroid (so positions stay real samples), its
// normal the normalized count-weighted average, its colour a Gaussian-weighted
// average over the cell and its 26 neighbours: the view-independent texture
// prefilter of Zwicker et al. 2001, §5, with standard deviation kPrefilterSigma
// cell sizes. Intensity and opacity are prefiltered the same way; the class and the returns
// (categorical) are the majority of the cell's input points, never averaged.
// Stored scalar fields (--attributes gps_time, ...) follow the same two rules
// by their kind.
#pragma once

#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

#include "surfel.h"

namespace surfcast {

// Standard deviation of the colour prefilter in units of the cell size: half a
// cell keeps frequencies the grid can hold and damps the ones it would alias.
inline constexpr double kPrefilterSigma = 0.5;
// A grid addresses at most 2^21 cells per axis (three axes in a 64-bit key).
inline constexpr uint32_t kMaxGridCells = 1u << 21;

struct SampleGrid {
    Vec3d origin;          // minimum corner, same frame as the surfel positions
    double cellSize = 1;
    uint32_t cells = 128;  // per axis, <= kMaxGridCells; points outside are clamped to the border
};

// The stored scalar fields of a set of surfels, quantized (inputs.h,
// ScalarQuantization): one row of `categorical.size()` values per surfel,
// found by Surfel::row.
struct ScalarTable {
    std::vector<bool> categorical;  // per field: majority when resampling, else the Gaussian prefilter
    std::vector<uint32_t> values;

    size_t fields() const { return categorical.size(); }
    const uint32_t* row(uint32_t r) const { return values.data() + size_t(r) * fields(); }
    // Appends a row (fields() values); returns its index.
    uint32_t append(const uint32_t* v) {
        const uint32_t r = uint32_t(values.size() / std::max<size_t>(fields(), 1));
        values.insert(values.end(), v, v + fields());
        return r;
    }
};

// Resample `points` on `grid`. withAttributes = false computes positions only
// (halo surfels, which serve as neighbours and are never stored). With a
// table of one or more fields, each new surfel's scalar row is appended to it
// (the points' rows must be in it).
std::vector<Surfel> resample(std::span<const Surfel> points, const SampleGrid& grid, bool withAttributes = true,
                             ScalarTable* table = nullptr);

// How many surfels resample(points, grid) returns: the grid's occupied cells.
size_t occupiedCells(std::span<const Surfel> points, const SampleGrid& grid);

}  // namespace surfcast
