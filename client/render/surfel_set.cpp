#include "surfel_set.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "block_codec.h"
#include "crc32.h"
#include "http_tile_source.h"
#include "object_store.h"
#include "octree_key.h"
#include "render_settings.h"
#include "tileset_reader.h"

namespace surfcast {

using gpu_types::GpuSurfel;

namespace {

uint16_t snorm16(float v) {
    v = std::clamp(std::isfinite(v) ? v : 0.f, -1.f, 1.f);
    return uint16_t(int16_t(std::lround(v * 32767.f)));
}
float fromSnorm16(uint16_t v) { return std::max(float(int16_t(v)) / 32767.f, -1.f); }
float signNotZero(float v) { return v < 0 ? -1.f : 1.f; }

}  // namespace

uint32_t packNormalOct(const Vec3f& n) {
    // Octahedral encoding (Cigolle et al. 2014): project onto the octahedron,
    // fold the lower half over the diagonals.
    float l1 = std::fabs(n.x) + std::fabs(n.y) + std::fabs(n.z);
    if (!(l1 > 0) || !std::isfinite(l1)) return 0;
    float x = n.x / l1, y = n.y / l1;
    if (n.z < 0) {
        float fx = (1 - std::fabs(y)) * signNotZero(x);
        float fy = (1 - std::fabs(x)) * signNotZero(y);
        x = fx;
        y = fy;
    }
    return uint32_t(snorm16(x)) | uint32_t(snorm16(y)) << 16;
}

Vec3f unpackNormalOct(uint32_t packed) {
    float x = fromSnorm16(uint16_t(packed & 0xffff)), y = fromSnorm16(uint16_t(packed >> 16));
    Vec3f n{x, y, 1 - std::fabs(x) - std::fabs(y)};
    float t = std::max(-n.z, 0.f);
    n.x += n.x >= 0 ? -t : t;
    n.y += n.y >= 0 ? -t : t;
    return normalizeOrZero(n);
}

uint32_t packColor(const Vec3f& rgb, float a) {
    auto u8 = [](float v) { return uint32_t(std::lround(std::clamp(std::isfinite(v) ? v : 0.f, 0.f, 1.f) * 255.f)); };
    return u8(rgb.x) | u8(rgb.y) << 8 | u8(rgb.z) << 16 | u8(a) << 24;
}

Vec3f unpackColor(uint32_t c) {
    return {float(c & 0xff) / 255.f, float(c >> 8 & 0xff) / 255.f, float(c >> 16 & 0xff) / 255.f};
}

uint32_t packEdgeWeights(const float ratios[4]) {
    uint32_t packed = 0;
    for (int i = 0; i < 4; ++i) {
        float v = std::isfinite(ratios[i]) ? ratios[i] / float(SC_EDGE_RATIO_MAX) : 1.f / float(SC_EDGE_RATIO_MAX);
        packed |= uint32_t(std::lround(std::clamp(v, 1.f / 255, 1.f) * 255.f)) << (8 * i);
    }
    return packed;
}

Vec3f tangentOf(const Vec3f& n) {
    Vec3f a = std::fabs(n.x) < 0.9f ? Vec3f{1, 0, 0} : Vec3f{0, 1, 0};
    return normalizeOrZero(cross(n, a));
}

void addSurfel(SurfelSet& set, const Vec3d& position, const Vec3f& normal, float radius,
               const Vec3f& color, float weight, uint32_t edge, float opacity) {
    Vec3d local = position - set.origin;
    set.surfels.push_back({float(local.x), float(local.y), float(local.z), radius, packNormalOct(normal),
                           packColor(color, opacity), weight, edge});
    set.translucent = set.translucent || opacity < 1.f;
    if (std::isfinite(position.x) && std::isfinite(position.y) && std::isfinite(position.z)) set.bounds.extend(position);
}

std::vector<uint32_t> sortMorton(SurfelSet& set) {
    std::vector<uint32_t> order(set.surfels.size());
    std::iota(order.begin(), order.end(), 0u);
    if (set.bounds.empty() || set.surfels.size() < 2) return order;
    Vec3d lo = set.bounds.min - set.origin;
    Vec3d extent = set.bounds.max - set.bounds.min;
    double scale = double((1u << 21) - 1) / std::max({extent.x, extent.y, extent.z, 1e-30});
    std::vector<std::pair<uint64_t, uint32_t>> keys(set.surfels.size());
    for (size_t i = 0; i < keys.size(); ++i) {
        const GpuSurfel& s = set.surfels[i];
        auto cell = [&](float v, double l) {
            double c = (double(v) - l) * scale;
            return uint32_t(std::isfinite(c) ? std::clamp(c, 0.0, double((1u << 21) - 1)) : 0.0);
        };
        keys[i] = {mortonCode(cell(s.px, lo.x), cell(s.py, lo.y), cell(s.pz, lo.z)), uint32_t(i)};
    }
    std::sort(keys.begin(), keys.end());
    std::vector<GpuSurfel> sorted(keys.size());
    for (size_t i = 0; i < keys.size(); ++i) {
        sorted[i] = set.surfels[keys[i].second];
        order[i] = keys[i].second;
    }
    set.surfels.swap(sorted);
    return order;
}

SurfelSet emptySurfelSet(const TilesetInfo& info, const Coloring& coloring) {
    SurfelSet set;
    set.origin = info.bounds.empty() ? info.rootMin : (info.bounds.min + info.bounds.max) * 0.5;
    set.hasWeights = info.weights != "none";
    set.kernelScale = info.kernelScale;
    set.normalsOriented = normalsOriented(info.normalSource);
    set.translucent = info.attribute(kOpacityAttribute) != nullptr;
    set.coloring = coloring;
    auto by = resolveColorBy(coloring.by, info);
    set.coloring.by = by ? *by : *resolveColorBy(ColorBy::Auto, info);
    // Measured appearance (RGB, intensity) is drawn unlit; the synthetic
    // colours of elevation, classes and returns are shaded (settingsForSet),
    // so the surface's shape still shows.
    set.hasColor = (set.coloring.by == ColorBy::Rgb && info.colorBits > 0) || set.coloring.by == ColorBy::Intensity;
    set.statistics = info.statistics;
    return set;
}

std::string decodingKey(const TilesetInfo& info, const Coloring& coloring) {
    const SurfelSet set = emptySurfelSet(info, coloring);
    std::string key;
    auto add = [&](double v) { key.append(reinterpret_cast<const char*>(&v), sizeof v); };
    for (double v : {set.origin.x, set.origin.y, set.origin.z, info.rootMin.x, info.rootMin.y, info.rootMin.z, info.rootEdge,
                     double(info.colorBits), double(set.coloring.by)})
        add(v);
    for (bool hidden : set.coloring.hidden) key += hidden ? '1' : '0';
    // What the block's decoding expects besides the record (blockExpectation).
    key += info.weights + '\n';
    for (const AttributeInfo& a : info.attributes) key += a.name + ',' + a.type + '\n';
    if (set.coloring.by == ColorBy::Intensity) {
        const AttributeInfo* intensity = info.attribute("intensity");
        for (double v : {intensity ? intensity->scale : 0, intensity ? intensity->offset : 0, info.statistics.intensityP2,
                         info.statistics.intensityP98})
            add(v);
    }
    if (set.coloring.by == ColorBy::Elevation) {
        add(info.statistics.elevationMin);
        add(info.statistics.elevationMax);
    }
    return key;
}

bool sameDecoding(const NodeRecord& a, const NodeRecord& b) {
    return a.key == b.key && a.blockCrc == b.blockCrc && a.blockSize == b.blockSize && a.surfelCount == b.surfelCount &&
           a.spacing == b.spacing && a.positionBits == b.positionBits &&
           ((a.flags ^ b.flags) & (kFlagHasRadius | kFlagEdgeWeights)) == 0;
}

void appendNode(SurfelSet& set, const TilesetInfo& info, const NodeRecord& node, const BlockData& b) {
    const int colorBits = info.colorBits;
    const float colorScale = colorBits > 0 ? 1.f / float((1u << colorBits) - 1) : 0.f;
    const AttributeInfo* intensity = info.attribute("intensity");
    const bool filter = set.coloring.anyHidden() && !b.classification.empty();
    const TilesetStatistics& st = set.statistics;
    const double zRange = st.elevationMax - st.elevationMin;
    for (size_t i = 0; i < b.size(); ++i) {
        if (filter && set.coloring.hidden[b.classification[i]]) continue;
        const Vec3d position = surfelPosition(info, node, b, i);
        Vec3f n = b.normals.empty() ? Vec3f{0, 0, 1} : Vec3f{b.normals[3 * i], b.normals[3 * i + 1], b.normals[3 * i + 2]};
        Vec3f c{0.8f, 0.8f, 0.8f};
        switch (set.coloring.by) {
            case ColorBy::Rgb:
            case ColorBy::Auto:
                if (!b.colors.empty())
                    c = {b.colors[3 * i] * colorScale, b.colors[3 * i + 1] * colorScale, b.colors[3 * i + 2] * colorScale};
                break;
            case ColorBy::Intensity:
                if (!b.intensity.empty() && intensity)
                    c = intensityColor(b.intensity[i] * intensity->scale + intensity->offset, st);
                break;
            case ColorBy::Elevation:
                c = viridis(zRange > 0 ? float((position.z - st.elevationMin) / zRange) : 0.5f);
                break;
            case ColorBy::Classification:
                if (!b.classification.empty()) c = classColor(b.classification[i]);
                break;
            case ColorBy::Return:
                if (!b.returnNumber.empty() && !b.numberOfReturns.empty())
                    c = returnColor(b.returnNumber[i], b.numberOfReturns[i]);
                break;
        }
        float r = b.radii.empty() ? node.spacing : b.radii[i];
        float w = b.weights.empty() ? 1.f : b.weights[i];
        uint32_t edge = b.edgeWeights.empty() ? 0 : packEdgeWeights(&b.edgeWeights[4 * i]);
        float opacity = b.opacity.empty() ? 1.f : float(b.opacity[i]) / 255.f;
        addSurfel(set, position, n, r, c, w, edge, opacity);
    }
}

namespace {

bool wantedNode(const NodeRecord& node, const LevelChoice& choice) {
    const bool leaf = node.childMask == 0;
    return node.surfelCount > 0 &&
           (choice.level < 0 ? leaf : (node.key.level == choice.level || (leaf && node.key.level < choice.level)));
}

Status checkChoice(const std::string& where, const TilesetInfo& info, const LevelChoice& choice, const Coloring& coloring) {
    if (choice.level >= info.levels)
        return Status::error(where + ": level " + std::to_string(choice.level) + " does not exist (the set has levels 0.." +
                             std::to_string(info.levels - 1) + ")");
    auto by = resolveColorBy(coloring.by, info);
    if (!by) return Status::error(where + ": " + by.status().message());
    return {};
}

}  // namespace

Result<SurfelSet> loadSurfelSet(const std::string& dir, const LevelChoice& choice, const Coloring& coloring,
                                const HttpOptions& http, size_t gpuBudget, TilesetInfo* infoOut) {
    auto reader = openTileset(dir, http);
    if (!reader) return reader.status();
    const TilesetInfo& info = reader->info();
    if (infoOut) *infoOut = info;
    SC_TRY(checkChoice(reader->describe(), info, choice, coloring));
    // A URL's set is streamed in whole: refused before any block is fetched
    // when it cannot fit the GPU budget.
    if (isUrl(dir) || isS3Url(dir)) {
        uint64_t surfels = 0;
        for (const NodeRecord& node : reader->nodes()) surfels += wantedNode(node, choice) ? node.surfelCount : 0;
        const uint64_t budget = gpuBudget ? gpuBudget : uint64_t(1) << 30;
        if (surfels * sizeof(gpu_types::GpuSurfel) > budget)
            return Status::error(reader->describe() + ": the " + std::string(choice.level < 0 ? "leaves" : "level") +
                                 " hold " + std::to_string(surfels) + " surfels (" +
                                 std::to_string((surfels * sizeof(gpu_types::GpuSurfel)) >> 20) +
                                 " MiB on the GPU), over the GPU budget of " + std::to_string(budget >> 20) +
                                 " MiB; view it with --lod, which streams what the view needs");
    }
    SurfelSet set = emptySurfelSet(info, coloring);
    for (const NodeRecord& node : reader->nodes()) {
        if (!wantedNode(node, choice)) continue;
        auto block = reader->readBlock(node);
        if (!block) return block.status();
        appendNode(set, info, node, *block);
    }
    sortMorton(set);
    return set;
}

int frontDirection(const SurfelSet& set) {
    const auto directions = frameDirections();
    std::array<size_t, 8> facing{};
    // A strided sample is plenty to rank eight directions.
    const size_t stride = std::max<size_t>(1, set.surfels.size() / 100000);
    for (size_t i = 0; i < set.surfels.size(); i += stride) {
        const Vec3d n = cast<double>(unpackNormalOct(set.surfels[i].normal));
        for (size_t d = 0; d < 8; ++d) facing[d] += dot(n, directions[d]) > 0;
    }
    size_t best = 0;
    for (size_t d = 1; d < 8; ++d)
        if (facing[d] > facing[best]) best = d;
    return 4 * facing[best] > 5 * facing[0] ? int(best) : 0;
}

}  // namespace surfcast
