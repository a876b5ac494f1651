#include "normals.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <tuple>

#include "grid_knn.h"
#include "neighbours.h"

namespace surfcast {

namespace {
double sqr(double x) { return x * x; }
}  // namespace

std::string orientationName(const OrientationRule& rule) {
    return rule.scanOrigin ? "estimated-scan-origin" : rule.up ? "estimated-up" : "estimated-outward";
}

void estimateNormals(std::span<Surfel> points, std::span<const Surfel> halo, const NormalContext& ctx) {
    // 1: to estimate and measure; 2: to measure only (kScanDkToMeasure).
    std::vector<uint8_t> todo(points.size());
    bool any = false;
    for (size_t i = 0; i < points.size(); ++i) {
        todo[i] = points[i].normal == Vec3f{} ? 1 : points[i].scanDk == kScanDkToMeasure && ctx.measure ? 2 : 0;
        any |= todo[i] != 0;
    }
    if (!any) return;

    // Float coordinates relative to the first point keep precision local.
    const Vec3d frame = points[0].position;
    std::vector<Vec3f> all;
    all.reserve(points.size() + halo.size());
    for (const Surfel& s : points) all.push_back(cast<float>(s.position - frame));
    for (const Surfel& s : halo) all.push_back(cast<float>(s.position - frame));

    // The normal of the plane fitted to a point's neighbours, oriented by its source's rule.
    auto estimate = [&](Surfel& s, std::span<const Vec3f> positions) {
        Vec3d normal{0, 0, 1};
        const size_t n = positions.size();
        if (n >= 3) {
            // Covariance about the mean, summed in double from offsets to one
            // of the neighbours, which keep the sums small.
            const Vec3f origin = positions[0];
            double sx = 0, sy = 0, sz = 0, xx = 0, xy = 0, xz = 0, yy = 0, yz = 0, zz = 0;
            for (const Vec3f& q : positions) {
                const double x = double(q.x) - origin.x, y = double(q.y) - origin.y, z = double(q.z) - origin.z;
                sx += x, sy += y, sz += z;
                xx += x * x, xy += x * y, xz += x * z, yy += y * y, yz += y * z, zz += z * z;
            }
            const double inv = 1.0 / double(n);
            Eigen::Matrix3d cov;
            cov(0, 0) = xx - sx * sx * inv;
            cov(1, 1) = yy - sy * sy * inv;
            cov(2, 2) = zz - sz * sz * inv;
            cov(1, 0) = cov(0, 1) = xy - sx * sy * inv;
            cov(2, 0) = cov(0, 2) = xz - sx * sz * inv;
            cov(2, 1) = cov(1, 2) = yz - sy * sz * inv;
            Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
            solver.computeDirect(cov);
            Eigen::Vector3d e = solver.eigenvectors().col(0);  // smallest eigenvalue first
            if (e.allFinite() && e.norm() > 0) normal = normalizeOrZero(Vec3d{e.x(), e.y(), e.z()});
        }
        const OrientationRule& rule = ctx.rules[s.source];
        Vec3d toward = rule.scanOrigin ? *rule.scanOrigin - s.position
                       : rule.up       ? Vec3d{0, 0, 1}
                                       : s.position - ctx.centre;
        if (dot(normal, toward) < 0) normal = normal * -1.0;
        s.normal = cast<float>(normal);
    };
    // The point's d_k and its k neighbours' spread off its tangent plane
    // (Surfel::scanDk), where k neighbours besides it were found; positions
    // nearest first, the point itself or a copy of it first. Where the build
    // merges copies, they are one point at its level: not its neighbours.
    auto measure = [&](Surfel& s, std::span<const Vec3f> positions, std::span<const float> dist2) {
        const size_t k = size_t(ctx.spacingK);
        const Vec3f self = cast<float>(s.position - frame), facing = s.normal;
        double off2 = 0;
        float dk = 0;
        size_t seen = 0;
        for (size_t j = 1; j < positions.size() && seen < k; ++j) {
            if (ctx.mergesCopies && dist2[j] == 0) continue;
            off2 += sqr(dot(positions[j] - self, facing));
            dk = std::sqrt(dist2[j]);
            ++seen;
        }
        if (seen < k) {  // too few found: its level judges it
            s.scanDk = -1;
            return;
        }
        const double spread = dk > 0 ? std::sqrt(off2 / double(k)) / dk : 0;
        s.scanDk = dk;
        s.scanSpread = uint16_t(std::min(65535.0, std::round(spread / kScanSpreadUnit)));
    };
    auto fit = [&](uint32_t query, std::span<const Vec3f> positions, std::span<const float> dist2) {
        if (todo[query] == 1) estimate(points[query], positions);
        if (ctx.measure) measure(points[query], positions, dist2);
    };

    const size_t own = points.size();
    GridKnn grid(all);
    if (!grid.tooCoarse()) {
        std::vector<Vec3f>().swap(all);
        grid.forEach(ctx.k, ctx.threads, [&](uint32_t i) { return i < own && todo[i]; },
                     [&](uint32_t query, const GridKnn::Neighbours& nbr) { fit(query, nbr.positions, nbr.dist2); });
        return;
    }
    // A dense scan the grid cannot resolve (GridKnn::tooCoarse): FLANN's
    // kd-tree, exact too, in batches of queries. A point with k or more
    // copies (all of them, halo included) has them as its k nearest, as in
    // the grid; the tree would visit every copy for each of them.
    grid = GridKnn({});
    std::vector<uint32_t> byPosition(all.size());
    for (uint32_t i = 0; i < byPosition.size(); ++i) byPosition[i] = i;
    std::sort(byPosition.begin(), byPosition.end(), [&](uint32_t a, uint32_t b) {
        return std::tie(all[a].x, all[a].y, all[a].z, a) < std::tie(all[b].x, all[b].y, all[b].z, b);
    });
    std::vector<uint8_t> stacked(own, 0);
    for (size_t b = 0; b < byPosition.size();) {
        size_t e = b + 1;
        while (e < byPosition.size() && all[byPosition[e]] == all[byPosition[b]]) ++e;
        if (e - b >= size_t(ctx.k))
            for (size_t j = b; j < e; ++j)
                if (byPosition[j] < own) stacked[byPosition[j]] = 1;
        b = e;
    }
    std::vector<uint32_t>().swap(byPosition);
    const NeighbourIndex tree(all, ctx.threads);
    constexpr size_t kBatch = 1 << 16;
    std::vector<uint32_t> queries;
    std::vector<Vec3f> at;
    std::vector<int> indices;
    std::vector<float> dist2;
    for (size_t from = 0; from < own; from += kBatch) {
        queries.clear();
        at.clear();
        for (size_t i = from; i < std::min(own, from + kBatch); ++i) {
            if (!todo[i]) continue;
            if (stacked[i]) {
                const std::vector<Vec3f> copies(size_t(ctx.k), all[i]);
                const std::vector<float> zero(size_t(ctx.k), 0.f);
                fit(uint32_t(i), copies, zero);
            } else {
                queries.push_back(uint32_t(i)), at.push_back(all[i]);
            }
        }
        tree.knn(at.data(), at.size(), ctx.k, &indices, &dist2);
        const size_t k = at.empty() ? 0 : indices.size() / at.size();
#pragma omp parallel for num_threads(std::max(1, ctx.threads)) schedule(dynamic, 256)
        for (size_t q = 0; q < queries.size(); ++q) {
            std::vector<Vec3f> near(k);
            for (size_t j = 0; j < k; ++j) near[j] = all[size_t(indices[q * k + j])];
            fit(queries[q], near, std::span<const float>(dist2.data() + q * k, k));
        }
    }
}

}  // namespace surfcast
