// surfcast-splat-stats: how large a set's splats are drawn, for the real
// scans of bench/defects_bench.py. Over every leaf (what surfcast-view draws
// by default): each surfel's radius r (its own, or its node's h) over its
// node's median d_8, the distance to the 8th nearest leaf surfel (FLANN), and
// over the median d_8 of every leaf (strays in nodes of their own, whose
// node median is their own far spacing, show only there); and
// in surfcast-view's default view at WxH, the share of the image covered by
// the largest 1 % of splats by projected radius, each taken as a circle of
// radius sqrt(2c) k r eta / z (c = 1, k the set's kernel scale; a tilted
// splat is an ellipse inside it), occlusion ignored.
// Usage: surfcast-splat-stats SET [--size WxH]. Prints one JSON line.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "camera.h"
#include "neighbours.h"
#include "render_settings.h"
#include "surfel_set.h"
#include "tileset_reader.h"

namespace {

using namespace surfcast;

constexpr int kK = 8;                      // d_8, the k of the build's spacing rule
constexpr double kLargestShare = 0.01;     // the largest 1 % of splats
constexpr double kWideRatio = 2;           // share_ratio_over_2: radii over twice their node's median d_8

double quantile(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    const size_t i = std::min(v.size() - 1, size_t(q * double(v.size() - 1) + 0.5));
    std::nth_element(v.begin(), v.begin() + long(i), v.end());
    return v[i];
}

int fail(const std::string& message) {
    std::fprintf(stderr, "surfcast-splat-stats: %s\n", message.c_str());
    return 1;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2 && !(argc == 4 && std::string(argv[2]) == "--size")) {
        std::fprintf(stderr, "usage: surfcast-splat-stats SET [--size WxH]\n");
        return 2;
    }
    int width = 640, height = 480;
    if (argc == 4 && std::sscanf(argv[3], "%dx%d", &width, &height) != 2) return fail("--size needs WxH");
    auto reader = TilesetReader::open(argv[1]);
    if (!reader) return fail(reader.status().message());
    const TilesetInfo& info = reader->info();

    // Every leaf, node by node: [first, end) of each node's surfels.
    SurfelSet set = emptySurfelSet(info);
    std::vector<size_t> nodeEnd;
    for (const NodeRecord& node : reader->nodes()) {
        if (node.childMask != 0) continue;
        auto block = reader->readBlock(node);
        if (!block) return fail(block.status().message());
        appendNode(set, info, node, *block);
        nodeEnd.push_back(set.surfels.size());
    }
    const size_t n = set.surfels.size();
    if (n < kK + 1) return fail("fewer than 9 surfels");

    std::vector<Vec3f> points(n);
    for (size_t i = 0; i < n; ++i) points[i] = {set.surfels[i].px, set.surfels[i].py, set.surfels[i].pz};
    NeighbourIndex index(points, 0);
    std::vector<int> nbr;
    std::vector<float> d2;
    index.knn(points.data(), n, kK + 1, &nbr, &d2);  // + 1: each finds itself first
    std::vector<double> ratio, all(n);
    ratio.reserve(n);
    for (size_t i = 0; i < n; ++i) all[i] = std::sqrt(double(d2[i * (kK + 1) + kK]));
    const double setMedian = quantile(all, 0.5);
    for (size_t i = 0; i < n; ++i) all[i] = setMedian > 0 ? set.surfels[i].radius / setMedian : 0;
    size_t first = 0;
    for (size_t end : nodeEnd) {
        std::vector<double> dk;
        for (size_t i = first; i < end; ++i) dk.push_back(std::sqrt(double(d2[i * (kK + 1) + kK])));
        const double median = quantile(dk, 0.5);
        for (size_t i = first; i < end; ++i)
            if (median > 0) ratio.push_back(set.surfels[i].radius / median);
        first = end;
    }

    // surfcast-view --headless's default camera (headless.cpp).
    const RenderSettings settings = settingsForSet(set.kernelScale, set.hasColor, set.normalsOriented, set.translucent);
    const Camera camera = frameBox(set.bounds, double(width) / height, 45, settings.backfaceCull ? frontDirection(set) : 0);
    const CameraAxes axes = cameraAxes(camera);
    const double eta = viewportScale(camera, height);
    const double reach = std::sqrt(2.0) * set.kernelScale;  // cutoff c = 1
    struct Disc {
        double x, y, r;
    };
    std::vector<Disc> discs;
    for (const auto& s : set.surfels) {
        const Vec3d p = set.origin + Vec3d{s.px, s.py, s.pz} - camera.eye;
        const double z = dot(p, axes.forward);
        if (!(z > 0)) continue;
        discs.push_back({0.5 * width + eta * dot(p, axes.right) / z, 0.5 * height - eta * dot(p, axes.up) / z,
                         eta * reach * s.radius / z});
    }
    std::sort(discs.begin(), discs.end(), [](const Disc& a, const Disc& b) { return a.r > b.r; });
    const size_t largest = std::max<size_t>(1, size_t(kLargestShare * double(discs.size())));
    std::vector<uint8_t> covered(size_t(width) * size_t(height), 0);
    for (size_t i = 0; i < std::min(largest, discs.size()); ++i) {
        const Disc& d = discs[i];
        const int x0 = std::max(0, int(std::floor(d.x - d.r))), x1 = std::min(width - 1, int(std::ceil(d.x + d.r)));
        const int y0 = std::max(0, int(std::floor(d.y - d.r))), y1 = std::min(height - 1, int(std::ceil(d.y + d.r)));
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                const double dx = x + 0.5 - d.x, dy = y + 0.5 - d.y;
                if (dx * dx + dy * dy <= d.r * d.r) covered[size_t(y) * size_t(width) + size_t(x)] = 1;
            }
    }
    size_t pixels = 0;
    for (uint8_t c : covered) pixels += c;
    std::printf("{\"splats\": %zu, \"ratio_p50\": %.4g, \"ratio_p90\": %.4g, \"ratio_p99\": %.4g, \"ratio_p999\": %.4g, "
                "\"ratio_max\": %.4g, \"share_ratio_over_2\": %.6g, \"set_ratio_p999\": %.4g, \"set_ratio_max\": %.4g, \"largest_1pc_px_radius_min\": %.4g, "
                "\"largest_1pc_image_share\": %.6g}\n",
                n, quantile(ratio, 0.5), quantile(ratio, 0.9), quantile(ratio, 0.99), quantile(ratio, 0.999),
                quantile(ratio, 1.0), double(std::count_if(ratio.begin(), ratio.end(), [](double r) { return r > kWideRatio; })) / double(ratio.size()),
                quantile(all, 0.999), quantile(all, 1.0), discs.empty() ? 0.0 : discs[std::min(largest, discs.size()) - 1].r,
                double(pixels) / double(size_t(width) * size_t(height)));
    return 0;
}
