// Grid resampling: one level of the LDC-style octree (DESIGN.md decision 2).
// At most one surfel per occupied cell of a regular grid: its position is the
// input point nearest the cell's centroid (so positions stay real samples), its
// normal the normalized count-weighted average, its colour a Gaussian-weighted
// average over the cell and its 26 neighbours: the view-independent texture
// prefilter of Zwicker et al. 2001, §5, with standard deviation kPrefilterSigma
// cell sizes. Intensity is prefiltered the same way; the class and the returns
// (categorical) are the majority of the cell's input points, never averaged.
#pragma once

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

// Resample `points` on `grid`. withAttributes = false computes positions only
// (halo surfels, which serve as neighbours and are never stored).
std::vector<Surfel> resample(std::span<const Surfel> points, const SampleGrid& grid, bool withAttributes = true);

}  // namespace surfcast
