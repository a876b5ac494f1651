#include "built_node.h"

#include <algorithm>
#include <cassert>
#include <cmath>

#include "block_codec.h"
#include "cones.h"

namespace surfcast {

namespace {
// Surfels of one least-squares solve at most (--texture-filter optimal): a
// larger node is solved in runs of this many, each with its halo.
constexpr uint32_t kFitGroupSurfels = 8192;
}  // namespace

double largestCell(const BuildContext& context, int level, std::span<BuiltNode* const> nodes) {
    double cell = context.edge(level) / context.options().grid;
    for (const BuiltNode* n : nodes) cell = std::max(cell, n->cell);
    return cell;
}

FitReport filterLevelTextures(const BuildContext& context, std::span<BuiltNode* const> nodes, std::span<const Surfel> halo,
                              int threads, StepTimes& steps) {
    FitReport fits;
    if (nodes.empty() || !context.anyTexture()) return fits;
    const BuildOptions& opt = context.options();
    ScopedTimer t(steps[kStepTextures]);
    auto fieldOf = [&](const Surfel& s) { return context.textureOf(s); };
    auto sigmaOf = [&](const BuiltNode& node, size_t i) {
        return opt.kernelScale * (node.level.radii.empty() ? node.level.h : node.level.radii[i]);
    };
    auto store = [](Surfel& s, const Vec3f& c) {
        for (int k = 0; k < 3; ++k) s.color[k] = uint16_t(std::lround(std::clamp(c[k], 0.f, 1.f) * 255.f) * 257);
    };
    // The view-independent EWA coefficients: the result for ewa, the
    // starting guess for optimal.
    for (BuiltNode* node : nodes) {
        std::vector<Surfel>& v = node->surfels;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 256)
        for (size_t i = 0; i < v.size(); ++i) {
            const TextureField* field = fieldOf(v[i]);
            Vec3f c;
            if (field && field->filter(v[i].position, v[i].normal, sigmaOf(*node, i), &c)) store(v[i], c);
        }
    }
    if (opt.textureFilter != BuildOptions::TextureFilter::Optimal) return fits;

    // The least-squares coefficients, one group per node, each textured
    // mesh on its own. Halo surfels (other chunks) have no h of their own
    // and take the level's median.
    std::vector<float> hs;
    for (BuiltNode* node : nodes) hs.push_back(node->level.h);
    std::nth_element(hs.begin(), hs.begin() + long(hs.size() / 2), hs.end());
    const double haloSigma = opt.kernelScale * hs[hs.size() / 2];
    FitParams params;
    params.cutoff = opt.cutoff;
    params.zt = kDefaultZt;
    params.threads = std::min(threads, kFitSolvesPerChunk);
    for (const auto& shared : context.textureFields()) {
        const TextureField* field = shared.get();
        if (!field) continue;
        std::vector<FitSurfel> fit;
        std::vector<std::pair<uint32_t, uint32_t>> groups;
        std::vector<std::pair<BuiltNode*, size_t>> from;  // the surfel each fitted one came from
        auto toFit = [](const Surfel& s, double sigma) {
            const double k = 1.0 / 65535;
            return FitSurfel{s.position, s.normal, sigma, Vec3f{float(s.color[0] * k), float(s.color[1] * k), float(s.color[2] * k)}};
        };
        for (BuiltNode* node : nodes) {
            const uint32_t begin = uint32_t(fit.size());
            for (size_t i = 0; i < node->surfels.size(); ++i)
                if (fieldOf(node->surfels[i]) == field) {
                    fit.push_back(toFit(node->surfels[i], sigmaOf(*node, i)));
                    from.push_back({node, i});
                }
            // Runs of a node's surfels (which lie in grid or Morton order) of
            // at most kFitGroupSurfels each, so that a solve's memory is bounded.
            const uint32_t n = uint32_t(fit.size()) - begin, parts = (n + kFitGroupSurfels - 1) / kFitGroupSurfels;
            for (uint32_t k = 0; k < parts; ++k) groups.push_back({begin + uint32_t(uint64_t(n) * k / parts), begin + uint32_t(uint64_t(n) * (k + 1) / parts)});
        }
        if (groups.empty()) continue;
        for (const Surfel& s : halo)
            if (fieldOf(s) == field) fit.push_back(toFit(s, haloSigma));
        FitReport report = field->fitOptimal(fit, groups, params);
        for (size_t i = 0; i < from.size(); ++i) store(from[i].first->surfels[from[i].second], fit[i].color);
        fits.add(report);
    }
    return fits;
}

NodeRecord keptRecord(const BuiltNode& node) {
    NodeRecord r;
    r.key = node.key;
    r.childMask = node.childMask;
    r.surfelCount = uint32_t(node.surfels.size());
    return r;
}

Result<EncodedNode> encodeNode(const BuildContext& context, const BuiltNode& node, const ScalarTable& scalars, StepTimes& steps) {
    assert((node.inputPoints || node.cell > 0) && "a resampled node knows its grid's cell");
    const BuildOptions& opt = context.options();
    const int colorBits = context.stats().colorBits;
    const size_t n = node.surfels.size();
    const int bits = context.positionBits(node.key, node.inputPoints ? 0 : node.cell);
    const double maxQ = double((uint64_t(1) << bits) - 1);
    const double step = context.edge(node.key.level) / maxQ;
    const Vec3d lo = context.nodeMinRel(node.key);
    BlockData block;
    block.positions.resize(3 * n);
    block.normals.resize(3 * n);
    if (colorBits) block.colors.resize(3 * n);
    if (context.stores(kLidarIntensity)) block.intensity.resize(n);
    if (context.stores(kLidarClassification)) block.classification.resize(n);
    if (context.stores(kLidarReturnNumber)) block.returnNumber.resize(n);
    if (context.stores(kLidarNumberOfReturns)) block.numberOfReturns.resize(n);
    if (context.storesOpacity()) block.opacity.resize(n);
    for (size_t f = 0; f < context.scalars().size(); ++f) {
        ScalarAttribute& a = block.scalars.emplace_back();
        a.bits = context.scalars()[f].bits;
        a.values.resize(n);
        for (size_t i = 0; i < n; ++i) a.values[i] = scalars.row(node.surfels[i].row)[f];
    }
    for (size_t i = 0; i < n; ++i) {
        const Surfel& s = node.surfels[i];
        for (int a = 0; a < 3; ++a) {
            block.positions[3 * i + a] = uint32_t(std::clamp(std::round((s.position[a] - lo[a]) / step), 0.0, maxQ));
            block.normals[3 * i + a] = s.normal[a];
        }
        if (colorBits)
            for (int c = 0; c < 3; ++c) block.colors[3 * i + c] = colorBits == 8 ? uint16_t(s.color[c] >> 8) : s.color[c];
        if (!block.intensity.empty()) block.intensity[i] = context.storedIntensity(s.intensity);
        if (!block.classification.empty()) block.classification[i] = s.classification;
        if (!block.returnNumber.empty()) block.returnNumber[i] = s.returns & 15;
        if (!block.numberOfReturns.empty()) block.numberOfReturns[i] = s.returns >> 4;
        if (!block.opacity.empty()) block.opacity[i] = s.alpha;
    }
    block.weights = node.level.weights;
    block.radii = node.level.radii;
    BlockCodecOptions codec;
    codec.codec = opt.blockCodec;
    codec.positionBits = bits;
    codec.normalBits = opt.normalBits;
    codec.colorBits = colorBits ? colorBits : 8;
    auto blob = [&] {
        ScopedTimer t(steps[kStepEncode]);
        return encodeBlock(block, codec);
    }();
    if (!blob) return Status::error("node " + node.key.name() + ": " + blob.status().message());

    const NormalCone cone = computeCone(node.surfels);
    EncodedNode out;
    NodeRecord& r = out.record;
    r.key = node.key;
    r.childMask = node.childMask;
    r.flags = uint16_t((cone.full ? kFlagConeFull : 0) | (block.radii.empty() ? 0 : kFlagHasRadius) |
                       (node.inputPoints ? kFlagInputPoints : 0));
    r.surfelCount = uint32_t(n);
    r.spacing = node.level.h;
    r.coneAxis = cone.axis;
    r.coneCosHalfAngle = cone.cosHalfAngle;
    r.positionBits = uint8_t(bits);
    out.blob = std::move(*blob);
    return out;
}

}  // namespace surfcast
