// k-nearest-neighbour queries in 3D: the only user of FLANN (an exact
// single kd-tree, the right FLANN index for three dimensions).
#pragma once

#include <cstddef>
#include <memory>
#include <vector>

#include "vec3.h"

namespace surfcast {

class NeighbourIndex {
public:
    // Indexes `points` (copied). threads: OpenMP threads used by queries.
    NeighbourIndex(const std::vector<Vec3f>& points, int threads);
    ~NeighbourIndex();
    NeighbourIndex(const NeighbourIndex&) = delete;
    NeighbourIndex& operator=(const NeighbourIndex&) = delete;

    size_t size() const { return size_; }
    // For each query: the k nearest indexed points, nearest first (a query that
    // is itself indexed finds itself first, at distance 0). k is clamped to
    // size(); indices and squared distances are k per query, row-major.
    void knn(const Vec3f* queries, size_t count, int k, std::vector<int>* indices, std::vector<float>* dist2) const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
    size_t size_ = 0;
};

}  // namespace surfcast
