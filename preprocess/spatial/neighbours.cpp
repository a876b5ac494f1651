#include "neighbours.h"

#include <algorithm>
// The one index type used, not flann/flann.hpp: flann::Index builds any index
// type from its parameters, so it compiles all of them (half a minute of
// this file's compile under ASan; bench/RELIABILITY.md, "CI stages").
#include <flann/algorithms/dist.h>
#include <flann/algorithms/kdtree_single_index.h>

namespace surfcast {

namespace {
// Points per kd-tree leaf: FLANN's default for KDTreeSingleIndex; larger leaves
// trade tree depth for linear scans and measured no faster here.
constexpr int kLeafSize = 10;
}  // namespace

struct NeighbourIndex::Impl {
    std::vector<Vec3f> data;
    std::unique_ptr<flann::KDTreeSingleIndex<flann::L2_Simple<float>>> index;
    int threads = 1;
};

NeighbourIndex::NeighbourIndex(const std::vector<Vec3f>& points, int threads) : impl_(new Impl), size_(points.size()) {
    impl_->data = points;
    impl_->threads = std::max(1, threads);
    if (size_ == 0) return;
    flann::Matrix<float> m(&impl_->data[0].x, size_, 3);
    impl_->index = std::make_unique<flann::KDTreeSingleIndex<flann::L2_Simple<float>>>(m, flann::KDTreeSingleIndexParams(kLeafSize));
    impl_->index->buildIndex();
}

NeighbourIndex::~NeighbourIndex() = default;

void NeighbourIndex::knn(const Vec3f* queries, size_t count, int k, std::vector<int>* indices,
                         std::vector<float>* dist2) const {
    k = int(std::min<size_t>(size_t(std::max(k, 0)), size_));
    indices->assign(count * size_t(k), -1);
    dist2->assign(count * size_t(k), 0.f);
    if (k == 0 || count == 0) return;
    flann::Matrix<float> q(const_cast<float*>(&queries[0].x), count, 3);
    flann::Matrix<int> idx(indices->data(), count, size_t(k));
    flann::Matrix<float> dst(dist2->data(), count, size_t(k));
    flann::SearchParams params;
    params.cores = impl_->threads;
    params.sorted = true;
    impl_->index->knnSearch(q, idx, dst, size_t(k), params);
}

}  // namespace surfcast
