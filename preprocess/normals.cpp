#include "normals.h"

#include <Eigen/Eigenvalues>
#include <algorithm>

#include "neighbours.h"

namespace surfcast {

namespace {
// Queries per FLANN call: bounds the k-per-query result arrays.
constexpr size_t kQueryBatch = 1 << 16;
}

std::string orientationName(const OrientationRule& rule) {
    return rule.scanOrigin ? "estimated-scan-origin" : rule.up ? "estimated-up" : "estimated-outward";
}

void estimateNormals(std::span<Surfel> points, std::span<const Surfel> halo, const NormalContext& ctx) {
    std::vector<size_t> todo;
    for (size_t i = 0; i < points.size(); ++i)
        if (points[i].normal == Vec3f{}) todo.push_back(i);
    if (todo.empty()) return;

    // Float coordinates relative to the first point keep precision local.
    const Vec3d frame = points[0].position;
    std::vector<Vec3f> all;
    all.reserve(points.size() + halo.size());
    for (const Surfel& s : points) all.push_back(cast<float>(s.position - frame));
    for (const Surfel& s : halo) all.push_back(cast<float>(s.position - frame));
    NeighbourIndex index(all, ctx.threads);

    std::vector<Vec3f> queries;
    std::vector<int> nbr;
    std::vector<float> d2;
    for (size_t start = 0; start < todo.size(); start += kQueryBatch) {
        size_t count = std::min(kQueryBatch, todo.size() - start);
        queries.resize(count);
        for (size_t q = 0; q < count; ++q) queries[q] = all[todo[start + q]];
        index.knn(queries.data(), count, ctx.k, &nbr, &d2);
        const size_t k = count ? nbr.size() / count : 0;
#pragma omp parallel for num_threads(ctx.threads) schedule(static)
        for (size_t q = 0; q < count; ++q) {
            Eigen::Vector3d mean = Eigen::Vector3d::Zero();
            int used = 0;
            for (size_t j = 0; j < k; ++j) {
                int id = nbr[q * k + j];
                if (id < 0) continue;
                mean += Eigen::Vector3d(all[id].x, all[id].y, all[id].z);
                ++used;
            }
            Surfel& s = points[todo[start + q]];
            Vec3d normal{0, 0, 1};
            if (used >= 3) {
                mean /= used;
                Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
                for (size_t j = 0; j < k; ++j) {
                    int id = nbr[q * k + j];
                    if (id < 0) continue;
                    Eigen::Vector3d d = Eigen::Vector3d(all[id].x, all[id].y, all[id].z) - mean;
                    cov += d * d.transpose();
                }
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
        }
    }
}

}  // namespace surfcast
