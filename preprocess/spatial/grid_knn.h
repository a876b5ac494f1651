// Exact k-nearest-neighbour search over surface samples, cell by cell on a
// uniform grid: the build's normals query every input point, and sharing one
// gathered 3×3×3 block of cells among all the queries of a cell costs about
// half a kd-tree descent per query (docs/ARCHITECTURE.md, "Normals"). FLANN
// (neighbours.h) stays the engine for the spacing h.
//
// Points are sorted along a Morton curve of 21 bits per axis over their
// bounding cube; the grid is the level of that curve whose occupied cells hold
// about kKnnPointsPerCell points each, overfull cells split finer
// (kKnnMaxCellPoints). A query takes the points of the 27 cells around its
// own and keeps the k nearest; when the k-th is farther than
// the block's nearest face, points outside the block could be nearer, and the
// query repeats on the next coarser level (a cell there is a contiguous range
// of the sorted points), up to the whole cube. The result is therefore exact:
// the same k-th-neighbour distances as any exact search.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "vec3.h"

namespace surfcast {

// Occupied cells hold about this many points (between it and 4x it for a
// surface: levels double the cell size): measured fastest for k = 16.
inline constexpr double kKnnPointsPerCell = 6;
// A cell of the grid's level holding more points than this (a dense scan
// beside sparse ones: the level suits the average) is searched cell by cell
// at finer levels, down to cells of at most this many (or the finest level),
// so that its queries do not each scan its whole block (BENCHMARKS.md,
// "Normals of a dense cluster beside sparse scans").
inline constexpr uint32_t kKnnMaxCellPoints = 256;

class GridKnn {
public:
    // Indexes `points` (copied, sorted). Empty sets are allowed.
    explicit GridKnn(std::span<const Vec3f> points);

    size_t size() const { return order_.size(); }
    int level() const { return level_; }
    // Whether a cell of the finest level searched (kFinestSplit) holds more
    // than kKnnMaxCellPoints points that are not all one position: 21 bits
    // per axis of the cube are too coarse for them (a dense scan beside others far away), and their
    // queries would each scan thousands of candidates; an adaptive search (a
    // kd-tree) answers them faster.
    bool tooCoarse() const { return tooCoarse_; }

    // Neighbours of one query: indices into the indexed points, their squared
    // distances and positions (as indexed), at most k (fewer only when fewer
    // points exist), nearest first. A query finds
    // itself at distance 0, or, in a stack of more than k coincident points,
    // k of the stack.
    struct Neighbours {
        std::span<const uint32_t> indices;
        std::span<const float> dist2;
        std::span<const Vec3f> positions;
    };
    using Visit = std::function<void(uint32_t query, const Neighbours&)>;

    // The k nearest neighbours of every indexed point i with wanted(i) (all
    // when wanted is empty), on `threads` OpenMP threads. visit runs
    // concurrently for different queries; each query is visited once.
    void forEach(int k, int threads, const std::function<bool(uint32_t)>& wanted, const Visit& visit) const;

private:
    static constexpr int kBits = 21;  // Morton bits per axis
    // The finest level overfull cells split to: its cells (edge / 2^19) are
    // about twice forEach's hair (edge * 1e-6), so a query's block can hold
    // its neighbours provably.
    static constexpr int kFinestSplit = kBits - 2;

    struct Block;
    // The block around a cell of `level`; at level_, `hint` is the cell's own
    // index, from which its neighbours are searched (they lie near it on the curve).
    void gather(int level, const uint32_t cell[3], size_t hint, Block* block) const;
    uint32_t lowerBound(uint64_t code) const;
    size_t findCell(uint64_t cellCode, size_t hint) const;  // index in cellCodes_, or cellCodes_.size()

    Vec3f lo_;
    double edge_ = 1;                 // cube edge
    int level_ = 0;                   // the grid's level (cell = edge / 2^level)
    std::vector<uint64_t> codes_;     // Morton codes, sorted
    std::vector<uint32_t> order_;     // sorted position → input index
    std::vector<Vec3f> sorted_;       // positions in sorted order
    std::vector<uint64_t> cellCodes_; // per occupied cell of level_, its code at that level, sorted
    std::vector<uint32_t> cellBegin_; // per occupied cell of level_, into the sorted order; one more at the end
    // The cells queries are answered by: those of level_, and in place of an
    // overfull one its occupied cells of a finer level.
    struct WorkCell {
        int level;
        uint32_t begin, end;  // its points in the sorted order
        uint32_t hint;        // the index of its cell of level_ in cellCodes_
    };
    std::vector<WorkCell> work_;
    bool tooCoarse_ = false;
};

}  // namespace surfcast
