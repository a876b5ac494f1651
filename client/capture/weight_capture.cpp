#include "weight_capture.h"

#include <algorithm>
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

}  // namespace

Result<std::vector<std::vector<float>>> captureWeights(gpu::Context& ctx, const TilesetReader& reader,
                                                       const std::vector<BlockData>& blocks, const CaptureOptions& options,
                                                       CaptureStats* stats) {
    auto start = std::chrono::steady_clock::now();
    const TilesetInfo& info = reader.info();
    const auto& nodes = reader.nodes();
    std::vector<std::vector<float>> weights(nodes.size());
    CaptureStats local;
    CaptureStats& st = stats ? *stats : local;
    st = {};

    auto renderer = SplatRenderer::create(ctx, {});
    if (!renderer) return renderer.status();
    RenderSettings settings;
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

        // Samples 1/S per own surfel, NaN where a view did not see it.
        const size_t count = set.surfels.size();
        std::vector<float> samples(count * directions.size(), NAN);
        std::vector<float> sums, depth;
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
                if (!(o.z >= near)) continue;
                Vec3f n = view->rotate(unpackNormalOct(g.normal));
                if (std::fabs(dot(n, o)) < kMinFacing * length(o)) continue;
                float x = 0.5f * options.size + view->eta * o.x / o.z, y = 0.5f * options.size - view->eta * o.y / o.z;
                if (!(x >= 0 && y >= 0 && x < options.size && y < options.size)) continue;
                size_t p = size_t(y) * options.size + size_t(x);
                // Visible at its centre: in front of the pushed-back nearest
                // surface (reversed Z: larger is nearer).
                if (!(near / o.z >= depth[p]) || !(sums[p] > 0)) continue;
                samples[i * directions.size() + v] = 1.f / sums[p];
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
            weights[n][local] = values[values.size() / 2];
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
    return weights;
}

}  // namespace surfcast
