#include "level_attributes.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>

#include "cell_grid.h"
#include "neighbours.h"
#include "tileset_format.h"

namespace surfcast {

namespace {

// The weight search grid's cell is the reach of the node at this percentile of
// h: one ring of cells serves it and every denser node; the few sparser ones
// search two rings or more.
constexpr double kWeightCellPercentile = 0.9;

// Neighbours facing away (the other side of a thin sheet, a close parallel
// surface) do not sample a surface: they count for neither d_k nor weights.
// An unoriented (zero) normal faces every side.
bool sameSide(const Vec3f& a, const Vec3f& b) { return a == Vec3f{} || b == Vec3f{} || dot(a, b) >= 0; }

// Neighbours the first d_k query fetches besides the query: with only k (8),
// a third of a real scan's queries find one facing away and are asked again
// for fetchK; 12 asks fewer again, for less in all (bench/BENCHMARKS.md, "What
// isolation costs on a real scan").
constexpr int kFirstFetch = 12;

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
    std::vector<uint32_t> owner;  // node index of each own point
    std::vector<size_t> firstOf(nodes.size());
    size_t own = 0;
    for (size_t i = 0; i < nodes.size(); ++i) {
        assert(!nodes[i]->surfels.empty() && "a level node holds at least one surfel");
        firstOf[i] = own;
        own += nodes[i]->surfels.size();
    }
    if (own == 0) return;
    const Vec3d frame = nodes[0]->surfels[0].position;
    points.reserve(own + extra.size());
    normals.reserve(own + extra.size());
    owner.reserve(own);
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

    // d_k of the surfels `queries` (indices into points): one FLANN query for
    // the kFirstFetch nearest each, and a second, for fetchK, only where fewer
    // than k of those face its side. The result is the same as fetching fetchK
    // at once, faster.
    NeighbourIndex index(points, params.threads);
    std::vector<Vec3f> queryPoints;
    std::vector<int> nbr;
    std::vector<float> d2;
    // Also each query's spread off its tangent plane: the RMS distance of those
    // k neighbours from it over d_k; +inf where no neighbour faces its side.
    auto kthDistances = [&](const std::vector<uint32_t>& queries, std::vector<float>* spread) {
        std::vector<float> dk(queries.size(), 0.f);
        spread->assign(queries.size(), 0.f);
        std::vector<uint32_t> pending(queries.size());
        for (size_t q = 0; q < queries.size(); ++q) pending[q] = uint32_t(q);
        const int first = std::max(params.spacingK, std::min(params.fetchK, kFirstFetch));
        for (int k : {first + 1, std::max(params.spacingK, params.fetchK) + 1}) {  // +1: the query itself
            queryPoints.resize(pending.size());
            for (size_t q = 0; q < pending.size(); ++q) queryPoints[q] = points[queries[pending[q]]];
            index.knn(queryPoints.data(), pending.size(), k, &nbr, &d2);
            const size_t kk = nbr.size() / std::max<size_t>(pending.size(), 1);
            std::vector<uint32_t> again;
            for (size_t q = 0; q < pending.size(); ++q) {
                const uint32_t self = queries[pending[q]];
                int seen = 0;
                float d = 0, off2 = 0;
                for (size_t j = 1; j < kk && seen < params.spacingK; ++j) {  // j = 0: the query itself
                    int id = nbr[q * kk + j];
                    if (id < 0 || !sameSide(normals[self], normals[size_t(id)])) continue;
                    d = std::sqrt(d2[q * kk + j]);
                    const float off = dot(points[size_t(id)] - points[self], normals[self]);
                    off2 += off * off;
                    ++seen;
                }
                dk[pending[q]] = d;  // fewer than k neighbours: the farthest one found
                (*spread)[pending[q]] = seen == 0 ? std::numeric_limits<float>::infinity()
                                        : d > 0    ? std::sqrt(off2 / float(seen)) / d
                                                   : 0.f;
                if (seen < params.spacingK && kk == size_t(k)) again.push_back(pending[q]);
            }
            pending.swap(again);
            if (pending.empty()) break;
        }
        return dk;
    };

    // h per node from an evenly strided subsample of its surfels (see the
    // header); nodes the sample finds irregular are queried whole, for their
    // per-surfel radii and an exact h. Nodes with isolated surfels keep h and
    // need each surfel's isolation: input points measured it when their normals
    // were estimated (Surfel::scanDk); other nodes are queried whole for it.
    assert((params.isolation == 0 || params.isolation >= 1) && "isolation is off or at least rho");
    auto isolated = [&](float dk, float spread, float rho) {
        return std::isinf(spread) || dk > params.isolation * rho || (dk > rho && spread > kScatteredSpread);
    };
    const bool isolating = params.radii && params.isolation > 0 && params.levelCell > 0;
    std::vector<uint32_t> queries;
    std::vector<float> spread;
    for (size_t i = 0; i < nodes.size(); ++i) {
        LevelNode& node = *nodes[i];
        const size_t n = node.surfels.size();
        const size_t stride = (n + kSpacingSamples - 1) / kSpacingSamples;
        queries.clear();
        for (size_t s = 0; s < n; s += stride) queries.push_back(uint32_t(firstOf[i] + s));
        std::vector<float> dk = kthDistances(queries, &spread);
        const float rho = float(kIsolationSpacing * (node.cell > 0 ? std::max(params.levelCell, node.cell) : std::max(params.levelCell, params.leafCell)));
        const bool measured = isolating && node.cell == 0 &&
                              std::all_of(node.surfels.begin(), node.surfels.end(), [](const Surfel& s) { return s.scanDk >= 0; });
        // Surfel s of the node isolated: by its measurement, or by its d_k and spread here.
        auto alone = [&](size_t s, float d, float sp) {
            const Surfel& p = node.surfels[s];
            return measured ? isolated(p.scanDk, float(p.scanSpread) * kScanSpreadUnit, rho) : isolated(d, sp, rho);
        };
        bool sparse = false;  // the sample's d_k as well, so that h <= isolation * rho where no radius is kept
        for (size_t s = 0; s < dk.size() && isolating; ++s) sparse = sparse || isolated(dk[s], spread[s], rho);
        for (size_t s = 0; s < n && measured && !sparse; ++s) sparse = alone(s, 0, 0);
        SpacingResult spacing = spacingRule(dk, params.fallbackSpacing);
        const bool exact = spacing.irregular && (params.radii || stride > 1);
        node.radii.clear();
        if (!exact && !sparse) {
            node.h = spacing.h;  // isolating, h <= the largest sampled d_k <= isolation * rho (see the header)
            continue;
        }
        std::vector<float> all;
        if (exact || !measured) {
            queries.clear();
            for (size_t s = 0; s < n; ++s) queries.push_back(uint32_t(firstOf[i] + s));
            all = kthDistances(queries, &spread);
        }
        if (exact) {
            std::vector<float> sorted = all;
            spacing = spacingRule(sorted, params.fallbackSpacing);
        }
        node.h = spacing.h;
        const bool own = spacing.irregular && params.radii;
        std::vector<float> radii(n);
        bool narrower = false;
        for (size_t s = 0; s < n; ++s) {
            const float d = all.empty() ? 0.f : all[s], sp = all.empty() ? 0.f : spread[s];
            float r = own ? std::clamp(d, spacing.minRadius, spacing.h) : spacing.h;
            if (isolating) r = std::min(r, float(alone(s, d, sp) ? rho : params.isolation * rho));
            narrower = narrower || r < spacing.h;
            radii[s] = r;
        }
        if (own || narrower) node.radii = std::move(radii);
    }
    if (!params.weights) return;

    // Weights, each over the tangent plane of its own surfel. A neighbour j
    // counts within sqrt(2c)·r_j of the surfel in its tangent plane and within
    // z_t·r of it along the normal (r, r_j: kernelScale times the surfel's own
    // radius or its node's h). So every neighbour with r_j <= r lies within
    // reach = r·sqrt(2c + z_t²) in 3D, and a fixed-radius search on a uniform
    // grid finds them all. Neighbours from a sparser node (r_j > r) beyond that
    // reach, at the border between the two, are left out: the k-nearest search
    // this replaces left them out too.
    const float cutoff2 = float(2.0 * params.cutoff);
    const double reachPerRadius = std::sqrt(cutoff2 + kDefaultZt * kDefaultZt) * (1 + 1e-5);
    std::vector<float> hs;
    for (LevelNode* n : nodes) hs.push_back(n->h);
    const double cell = params.kernelScale * percentile(hs, kWeightCellPercentile) * reachPerRadius;
    if (!(cell > 0)) return;
    CellGrid grid(points, float(cell));
    // Positions, normals and kernel radii in the grid's order, so that the
    // inner loop reads runs of memory. Halo surfels get radius 0: they are
    // taken at the querying surfel's width.
    const std::vector<uint32_t>& order = grid.order();
    std::vector<Vec3f> gp(order.size()), gn(order.size());
    std::vector<float> gr(order.size(), 0.f);
    for (size_t s = 0; s < order.size(); ++s) {
        uint32_t i = order[s];
        gp[s] = points[i];
        gn[s] = normals[i];
        if (i < own) {
            const LevelNode& node = *nodes[owner[i]];
            size_t l = i - firstOf[owner[i]];
            gr[s] = float(params.kernelScale * (node.radii.empty() ? node.h : node.radii[l]));
        }
    }
    for (LevelNode* n : nodes) n->weights.assign(n->surfels.size(), 1.f);
    // Cell by cell: the cells around one serve all of its surfels.
    std::vector<std::pair<uint32_t, uint32_t>> runs;
#pragma omp parallel for num_threads(params.threads) schedule(dynamic, 256) firstprivate(runs)
    for (size_t cellIndex = 0; cellIndex < grid.cells(); ++cellIndex) {
        int64_t ring = 0;
        for (uint32_t s = grid.begin(cellIndex); s < grid.end(cellIndex); ++s)
            ring = std::max(ring, int64_t(std::ceil(gr[s] * reachPerRadius / cell)));
        if (ring == 0) continue;  // halo surfels only, or no radius
        grid.near(cellIndex, ring, &runs);
        for (uint32_t self = grid.begin(cellIndex); self < grid.end(cellIndex); ++self) {
            const float r = gr[self];
            if (!(r > 0)) continue;
            const Vec3f p = gp[self], n = gn[self];
            const float maxOffset = float(kDefaultZt) * r;
            float sum = 0;
            for (auto [first, last] : runs)
                for (uint32_t o = first; o < last; ++o) {
                    const Vec3f d = gp[o] - p;
                    const float along = dot(d, n);
                    // A neighbour off the tangent plane by more than z_t (a close
                    // parallel surface, the other sheet of a crossing) is hidden or
                    // hides this one when rendered: it does not blend, so it does
                    // not count. Neither does one facing away (sameSide).
                    if (std::fabs(along) > maxOffset || !sameSide(n, gn[o])) continue;
                    // Each neighbour's kernel has its own width, as the renderer
                    // draws it; halo surfels (other chunks) are taken at this one's.
                    const float rj = gr[o] > 0 ? gr[o] : r;
                    const float y2 = (dot(d, d) - along * along) / (rj * rj);  // tangent-plane distance²
                    if (y2 <= cutoff2) sum += std::exp(-0.5f * y2);
                }
            const uint32_t i = order[self];
            nodes[owner[i]]->weights[i - firstOf[owner[i]]] = 1.f / std::max(sum, 1.f);
        }
    }
}

}  // namespace surfcast
