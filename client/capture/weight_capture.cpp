#include "weight_capture.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "cpu_reference.h"
#include "splat_renderer.h"

namespace surfcast {

namespace {

// Unit directions spread evenly over the sphere (golden-angle spiral).
std::vector<Vec3d> fibonacciSphere(int n) {
    std::vector<Vec3d> dirs;
    const double golden = M_PI * (3 - std::sqrt(5.0));
    for (int i = 0; i < n; ++i) {
        double z = 1 - 2 * (i + 0.5) / n, r = std::sqrt(std::max(0.0, 1 - z * z));
        dirs.push_back({r * std::cos(golden * i), r * std::sin(golden * i), z});
    }
    return dirs;
}

constexpr double kCaptureFovDegrees = 40;
// Views that see a surfel at a grazing angle are not sampled: there the ray
// through its centre pixel meets its neighbours' splats far from where they
// overlap it on the surface, and S is off (measured: bright blotches).
constexpr float kMinFacing = 0.3f;
// The tangent points (edge weights) are sampled only from frontal views: from
// an oblique one a point r from the centre can land past a silhouette, where S
// is only the surfel's own fringe (measured: 12% of the bunny's surfels taken
// for edges at kMinFacing).
constexpr float kMinEdgeFacing = 0.7f;

}  // namespace

Result<CapturedWeights> captureWeights(gpu::Context& ctx, const TilesetReader& reader, const std::vector<BlockData>& blocks,
                                       const CaptureOptions& options, CaptureStats* stats) {
    auto start = std::chrono::steady_clock::now();
    const TilesetInfo& info = reader.info();
    const auto& nodes = reader.nodes();
    CapturedWeights result;
    std::vector<std::vector<float>>& weights = result.weights;
    result.edgeWeights.resize(nodes.size());
    weights.resize(nodes.size());
    CaptureStats local;
    CaptureStats& st = stats ? *stats : local;
    st = {};

    auto renderer = SplatRenderer::create(ctx, {});
    if (!renderer) return renderer.status();
    RenderSettings settings;
    settings.kernelScale = float(info.kernelScale);  // the kernel the weights are for
    settings.zt = options.zt;
    settings.cutoff = options.cutoff;
    const Vec3d centre = info.bounds.empty() ? info.rootMin : (info.bounds.min + info.bounds.max) * 0.5;
    // The bounding sphere; at least the root box (a one-point set has no extent).
    const double radius = std::max({info.bounds.empty() ? 0.0 : 0.5 * length(info.bounds.max - info.bounds.min),
                                    0.5 * info.rootEdge, 1e-6});
    const double distance = radius / std::sin(0.5 * kCaptureFovDegrees * M_PI / 180);
    const std::vector<Vec3d> directions = fibonacciSphere(options.views);

    for (int level = 0; level < info.levels; ++level) {
        // The level's surface: its nodes plus the leaves above it. Only the
        // level's own nodes get weights here; the leaves got theirs at their level.
        SurfelSet set;
        set.origin = centre;
        std::vector<std::pair<uint32_t, uint32_t>> owner;  // (node, surfel) per set entry; node = UINT32_MAX: context
        for (size_t n = 0; n < nodes.size(); ++n) {
            const NodeRecord& node = nodes[n];
            bool own = node.key.level == level;
            if (!own && !(node.childMask == 0 && node.key.level < level)) continue;
            const BlockData& b = blocks[n];
            for (size_t i = 0; i < b.size(); ++i) {
                Vec3f nrm{b.normals[3 * i], b.normals[3 * i + 1], b.normals[3 * i + 2]};
                float r = b.radii.empty() ? node.spacing : b.radii[i];
                addSurfel(set, reader.position(node, b, i), nrm, r, {1, 1, 1});
                owner.push_back({own ? uint32_t(n) : UINT32_MAX, uint32_t(i)});
            }
        }
        std::vector<uint32_t> order = sortMorton(set);
        if (Status s = renderer.value()->upload(set); !s) return s;

        // Samples 1/S per own surfel, NaN where a view did not see it; and the
        // sums of 1/S at its four tangent points (Ren's per-vertex weights;
        // averaged, not medians, to keep memory at 32 bytes per surfel).
        const size_t count = set.surfels.size();
        std::vector<float> samples(count * directions.size(), NAN);
        std::vector<float> edgeSum(4 * count, 0.f);
        std::vector<uint16_t> edgeCount(4 * count, 0);
        std::vector<float> sums, depth;
        // The pixel of camera-space point o when it is visible there, else -1.
        auto visiblePixel = [&](const ViewTransform& view, const Vec3f& o, float near) -> long {
            if (!(o.z >= near)) return -1;
            const PixelPoint s = view.project(o);
            if (!(s.x >= 0 && s.y >= 0 && s.x < options.size && s.y < options.size)) return -1;
            size_t p = size_t(s.y) * options.size + size_t(s.x);
            // In front of the pushed-back nearest surface (reversed Z: larger is nearer).
            if (!(near / o.z >= depth[p]) || !(sums[p] > 0)) return -1;
            return long(p);
        };
        // S at the exact projection of o (bilinear between pixel centres, over
        // the neighbours that show the same surface as pixel p): with narrow
        // kernels S changes within a pixel, and the nearest pixel centre can be
        // half a pixel off the surfel.
        auto sumAt = [&](const ViewTransform& view, const Vec3f& o, size_t p) {
            const int n = options.size;
            const PixelPoint s = view.project(o);
            float x = s.x - 0.5f, y = s.y - 0.5f;  // relative to pixel centres
            int x0 = std::clamp(int(std::floor(x)), 0, n - 2), y0 = std::clamp(int(std::floor(y)), 0, n - 2);
            float fx = std::clamp(x - x0, 0.f, 1.f), fy = std::clamp(y - y0, 0.f, 1.f);
            float total = 0, weight = 0;
            for (int dy = 0; dy < 2; ++dy)
                for (int dx = 0; dx < 2; ++dx) {
                    size_t q = size_t(y0 + dy) * n + size_t(x0 + dx);
                    // Same surface: depth within 1% of the centre pixel's.
                    if (!(sums[q] > 0) || std::fabs(depth[q] - depth[p]) > 0.01f * depth[p]) continue;
                    float w = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy);
                    total += w * sums[q];
                    weight += w;
                }
            return weight > 0 ? total / weight : sums[p];
        };
        // Per own surfel, once: the world normal and the tangent points +r s,
        // -r s, +r t, -r t (the basis the renderer's edgeFactor uses).
        std::vector<Vec3f> normalOf(count);
        std::vector<std::array<Vec3f, 4>> tangentPoints(count);
        for (size_t i = 0; i < count; ++i) {
            if (owner[order[i]].first == UINT32_MAX) continue;
            const auto& g = set.surfels[i];
            const Vec3f local{g.px, g.py, g.pz}, nw = unpackNormalOct(g.normal);
            const Vec3f sw = tangentOf(nw), tw = cross(nw, sw);
            const float r = g.radius * settings.kernelScale;
            normalOf[i] = nw;
            tangentPoints[i] = {local + sw * r, local + sw * -r, local + tw * r, local + tw * -r};
        }
        for (size_t v = 0; v < directions.size(); ++v) {
            Camera cam{centre + directions[v] * distance, centre,
                       std::fabs(directions[v].z) < 0.9 ? Vec3d{0, 0, 1} : Vec3d{0, 1, 0}, kCaptureFovDegrees};
            auto view = makeViewTransform(cam, centre, options.size, options.size);
            if (!view) return view.status();
            if (Status s = renderer.value()->capture(*view, settings, &sums, &depth); !s) return s;
            const float near = renderer.value()->nearPlane(*view);
            ++st.renders;
            for (size_t i = 0; i < count; ++i) {
                if (owner[order[i]].first == UINT32_MAX) continue;
                const auto& g = set.surfels[i];
                Vec3f o = view->apply({g.px, g.py, g.pz});
                float facing = std::fabs(dot(view->rotate(normalOf[i]), o)) / length(o);
                if (!(facing >= kMinFacing)) continue;
                long p = visiblePixel(*view, o, near);
                if (p < 0) continue;
                samples[i * directions.size() + v] = 1.f / sumAt(*view, o, size_t(p));
                if (facing < kMinEdgeFacing) continue;
                for (int k = 0; k < 4; ++k) {
                    long q = visiblePixel(*view, view->apply(tangentPoints[i][size_t(k)]), near);
                    if (q < 0) continue;
                    edgeSum[4 * i + k] += 1.f / sums[size_t(q)];
                    ++edgeCount[4 * i + k];
                }
            }
        }

        // Median per surfel; fallbacks for the unseen.
        std::vector<float> values;
        std::vector<double> nodeSum(nodes.size(), 0);
        std::vector<size_t> nodeSeen(nodes.size(), 0);
        for (size_t n = 0; n < nodes.size(); ++n)
            if (nodes[n].key.level == level) weights[n].assign(blocks[n].size(), NAN);
        for (size_t i = 0; i < count; ++i) {
            auto [n, local] = owner[order[i]];
            if (n == UINT32_MAX) continue;
            values.clear();
            for (size_t v = 0; v < directions.size(); ++v)
                if (float s = samples[i * directions.size() + v]; !std::isnan(s)) values.push_back(s);
            ++st.surfels;
            if (values.empty()) continue;
            std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
            float w = values[values.size() / 2];
            weights[n][local] = w;
            float ratios[4];
            bool edge = false;
            for (int k = 0; k < 4; ++k) {
                ratios[k] = edgeCount[4 * i + k] ? std::min(edgeSum[4 * i + k] / edgeCount[4 * i + k] / w, float(SC_EDGE_RATIO_MAX)) : 1.f;
                edge = edge || ratios[k] > kEdgeRatioThreshold;
            }
            if (edge && options.edgeWeights) {
                auto& e = result.edgeWeights[n];
                if (e.empty()) e.assign(4 * blocks[n].size(), 1.f);
                std::copy(ratios, ratios + 4, e.begin() + 4 * local);
                ++st.edges;
            }
            nodeSum[n] += weights[n][local];
            ++nodeSeen[n];
            ++st.seen;
        }
        for (size_t n = 0; n < nodes.size(); ++n) {
            if (nodes[n].key.level != level) continue;
            float fallback = nodeSeen[n] ? float(nodeSum[n] / nodeSeen[n]) : 1.f;
            for (size_t i = 0; i < weights[n].size(); ++i)
                if (std::isnan(weights[n][i])) weights[n][i] = blocks[n].weights.empty() ? fallback : blocks[n].weights[i];
        }
        if (options.progress)
            std::fprintf(stderr, "capture: level %d, %zu surfels, %zu views\n", level, count, directions.size());
    }
    st.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return result;
}

}  // namespace surfcast
