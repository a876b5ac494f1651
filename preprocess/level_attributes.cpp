#include "level_attributes.h"

#include <algorithm>
#include <cmath>

#include "neighbours.h"
#include "tileset_format.h"

namespace surfcast {

namespace {
constexpr size_t kQueryBatch = 1 << 16;  // bounds the k-per-query result arrays

float percentile(std::vector<float>& v, double p) {
    size_t i = std::min(v.size() - 1, size_t(p * double(v.size() - 1) + 0.5));
    std::nth_element(v.begin(), v.begin() + long(i), v.end());
    return v[i];
}
}  // namespace

SpacingResult spacingRule(std::vector<float>& dk, double fallback) {
    SpacingResult r;
    std::erase_if(dk, [](float d) { return !(d > 0) || !std::isfinite(d); });
    if (dk.empty()) {
        r.h = float(fallback);
        return r;
    }
    r.h = percentile(dk, kSpacingPercentile);
    r.minRadius = percentile(dk, kIrregularPercentile);
    r.irregular = r.h > kIrregularRatio * r.minRadius;
    return r;
}

void computeLevelAttributes(std::span<LevelNode* const> nodes, std::span<const Surfel> extra, const LevelParams& params) {
    std::vector<Vec3f> points;
    std::vector<Vec3f> normals;
    std::vector<uint32_t> owner;  // node index of each point; extra points get nodes.size()
    size_t own = 0;
    for (LevelNode* n : nodes) own += n->surfels.size();
    if (own == 0) return;
    const Vec3d frame = nodes[0]->surfels[0].position;
    points.reserve(own + extra.size());
    for (size_t i = 0; i < nodes.size(); ++i)
        for (const Surfel& s : nodes[i]->surfels) {
            points.push_back(cast<float>(s.position - frame));
            normals.push_back(s.normal);
            owner.push_back(uint32_t(i));
        }
    for (const Surfel& s : extra) {
        points.push_back(cast<float>(s.position - frame));
        normals.push_back(s.normal);
    }
    NeighbourIndex index(points, params.threads);
    const int k = std::max(params.spacingK, params.weights ? params.weightK : 0) + 1;  // +1: the query itself

    // One kNN query per surfel; the neighbour lists (not the distances, which
    // are cheap to recompute) are kept for the weights, which need every node's h.
    std::vector<uint32_t> neighbours;  // kk per own surfel; UINT32_MAX: none
    size_t kk = 0;
    std::vector<float> dk(own);
    std::vector<int> nbr;
    std::vector<float> d2;
    // Neighbours facing away (the other side of a thin sheet, a close parallel
    // surface) do not sample this surface: they count for neither d_k nor weights.
    auto sameSide = [&](size_t self, uint32_t other) {
        return normals[other] == Vec3f{} || normals[self] == Vec3f{} || dot(normals[other], normals[self]) >= 0;
    };
    for (size_t start = 0; start < own; start += kQueryBatch) {
        size_t count = std::min(kQueryBatch, own - start);
        index.knn(points.data() + start, count, k, &nbr, &d2);
        kk = nbr.size() / count;
        neighbours.resize(own * kk);
        for (size_t q = 0; q < count; ++q) {
            int seen = 0;
            float d = 0;
            for (size_t j = 0; j < kk; ++j) {
                int id = nbr[q * kk + j];
                uint32_t other = id < 0 ? UINT32_MAX : uint32_t(id);
                neighbours[(start + q) * kk + j] = other;
                if (j == 0 || other == UINT32_MAX || seen >= params.spacingK || !sameSide(start + q, other)) continue;
                d = std::sqrt(d2[q * kk + j]);
                ++seen;
            }
            dk[start + q] = d;  // fewer than k neighbours: the farthest one found
        }
    }
    std::vector<int>().swap(nbr);
    std::vector<float>().swap(d2);
    std::vector<SpacingResult> spacing(nodes.size());
    size_t offset = 0;
    for (size_t i = 0; i < nodes.size(); ++i) {
        size_t n = nodes[i]->surfels.size();
        std::vector<float> mine(dk.begin() + long(offset), dk.begin() + long(offset + n));
        spacing[i] = spacingRule(mine, params.fallbackSpacing);
        nodes[i]->h = spacing[i].h;
        nodes[i]->radii.clear();
        if (spacing[i].irregular && params.radii) {
            nodes[i]->radii.resize(n);
            for (size_t s = 0; s < n; ++s)
                nodes[i]->radii[s] = std::clamp(dk[offset + s], spacing[i].minRadius, spacing[i].h);
        }
        offset += n;
    }
    if (!params.weights) return;

    // Pass 2: weights, each over the tangent plane of its own surfel.
    std::vector<size_t> firstOf(nodes.size());
    for (size_t i = 0, o = 0; i < nodes.size(); o += nodes[i]->surfels.size(), ++i) {
        firstOf[i] = o;
        nodes[i]->weights.assign(nodes[i]->surfels.size(), 1.f);
    }
    const double cutoff2 = 2.0 * params.cutoff;
#pragma omp parallel for num_threads(params.threads) schedule(static)
    for (size_t self = 0; self < own; ++self) {
        LevelNode* node = nodes[owner[self]];
        size_t local = self - firstOf[owner[self]];
        double r = params.kernelScale * (node->radii.empty() ? node->h : node->radii[local]);
        if (!(r > 0)) continue;
        // Each neighbour's kernel has its own width, as the renderer draws it;
        // halo surfels (other chunks) are taken at this surfel's width.
        auto radiusOf = [&](uint32_t other) {
            if (other >= own) return r;
            const LevelNode* o = nodes[owner[other]];
            size_t l = other - firstOf[owner[other]];
            double ro = params.kernelScale * (o->radii.empty() ? o->h : o->radii[l]);
            return ro > 0 ? ro : r;
        };
        Vec3d n = cast<double>(normals[self]);
        double sum = 0;
        for (size_t j = 0; j < kk; ++j) {
            uint32_t other = neighbours[self * kk + j];
            if (other == UINT32_MAX || !sameSide(self, other)) continue;
            Vec3d d = cast<double>(points[other] - points[self]);
            // A neighbour off the tangent plane by more than z_t (a close
            // parallel surface, the other sheet of a crossing) is hidden or
            // hides this one when rendered: it does not blend, so it does not count.
            if (std::fabs(dot(d, n)) > kDefaultZt * r) continue;
            Vec3d t = d - n * dot(d, n);  // tangent-plane component
            double rj = radiusOf(other);
            double y2 = dot(t, t) / (rj * rj);
            if (y2 <= cutoff2) sum += std::exp(-0.5 * y2);
        }
        node->weights[local] = float(1.0 / std::max(sum, 1.0));
    }
}

}  // namespace surfcast
