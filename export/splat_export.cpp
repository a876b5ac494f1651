#include "splat_export.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "lod_selection.h"

namespace surfcast {

Vec3d toSplatAxes(const Vec3d& v, SplatAxes axes) {
    return axes == SplatAxes::YUp ? Vec3d{v.x, v.z, -v.y} : Vec3d{v.x, -v.z, v.y};
}

Status checkFiniteSurfels(const TilesetReader& set, const NodeRecord& node, const BlockData& block) {
    for (float v : block.normals)
        if (!std::isfinite(v)) return Status::error(set.describe() + ": node " + node.key.name() + ": a normal is not a finite number");
    for (float v : block.radii)
        if (!(std::isfinite(v) && v >= 0)) return Status::error(set.describe() + ": node " + node.key.name() + ": a radius is not a finite number");
    return {};
}

Gaussian surfelGaussian(const TilesetReader& set, const NodeRecord& node, const BlockData& b, size_t i, const Vec3d& centre,
                        const GaussianOptions& options, SplatAxes axes) {
    const TilesetInfo& info = set.info();
    const size_t n = b.size();
    const double top = info.colorBits > 0 ? double((1u << info.colorBits) - 1) : 1.0;
    Gaussian g;
    g.position = cast<float>(toSplatAxes(set.position(node, b, i) - centre, axes));
    const Vec3d normal = b.normals.size() == 3 * n ? Vec3d{b.normals[3 * i], b.normals[3 * i + 1], b.normals[3 * i + 2]} : Vec3d{0, 0, 1};
    g.normal = cast<float>(toSplatAxes(normalizeOrZero(normal), axes));
    g.sigma = float(options.sigmaScale * info.kernelScale * (b.radii.empty() ? node.spacing : b.radii[i]));
    g.thickness = float(options.thickness);
    g.opacity = float((b.opacity.empty() ? 1.0 : b.opacity[i] / 255.0) * options.opacity);
    g.color = {1, 1, 1};
    if (info.colorBits > 0)
        for (int c = 0; c < 3; ++c) g.color[c] = float(b.colors[3 * i + size_t(c)] / top);
    return g;
}

Result<SplatFileReport> writeSplatFile(const TilesetReader& set, SplatFormat format, const SplatCut& cut, const GaussianOptions& options,
                                       std::FILE* f, const std::function<void(size_t, size_t)>& progress) {
    const TilesetInfo& info = set.info();
    const std::vector<NodeRecord>& nodes = set.nodes();
    // The nodes of level L's cut, and their surfels.
    const auto inCut = [&](const NodeRecord& n, int level) {
        return level < 0 ? n.childMask == 0 : n.key.level == level || (n.key.level < level && n.childMask == 0);
    };
    const auto surfelsOf = [&](int level) {
        uint64_t sum = 0;
        for (const NodeRecord& n : nodes) sum += inCut(n, level) ? n.surfelCount : 0;
        return sum;
    };
    SplatFileReport report;
    std::vector<size_t> chosen;
    if (cut.camera) {
        // The client's own selection, every node at hand (lod_selection.h).
        LodParams params;
        params.targetPixels = cut.lodPixels;
        if (cut.budget > 0) params.splatBudget = size_t(std::min<uint64_t>(cut.budget, SIZE_MAX));
        const LodSelector selector(info, nodes);
        for (const SelectedNode& s : selector.select(*cut.camera, cut.width, cut.height, params, [](uint32_t) { return true; }))
            if (nodes[s.index].surfelCount > 0) chosen.push_back(s.index);
        report.cut = "the camera's view";
    } else {
        int level = cut.level;
        if (cut.budget > 0 && surfelsOf(-1) > cut.budget) {
            level = 0;
            while (level + 1 < info.levels && surfelsOf(level + 1) <= cut.budget) ++level;
        }
        report.cut = level < 0 ? "leaves" : "level " + std::to_string(level);
        for (size_t i = 0; i < nodes.size(); ++i)
            if (inCut(nodes[i], level) && nodes[i].surfelCount > 0) chosen.push_back(i);
    }
    std::sort(chosen.begin(), chosen.end(), [&](size_t a, size_t b) { return nodes[a].key < nodes[b].key; });
    uint64_t count = 0;
    for (size_t i : chosen) count += nodes[i].surfelCount;
    if (count == 0) return Status::error(set.describe() + ": " + report.cut + " holds no surfels");
    if (format == SplatFormat::Spz && count > SpzWriter::kMaxPoints)
        return Status::error(set.describe() + ": " + report.cut + " holds " + std::to_string(count) +
                             " surfels, more than SPZ's 10 million (--level or --splat-budget chooses fewer)");

    const Vec3d origin = (info.bounds.min + info.bounds.max) * 0.5;
    const SplatAxes axes = format == SplatFormat::Ply ? SplatAxes::YDown : SplatAxes::YUp;
    const auto failed = [&] { return Status::error(std::string("write failed (") + std::strerror(errno) + ")"); };
    // Every position lies within the bounds grown by the coarsest node's step.
    double step = 0, half = 0;
    for (size_t i : chosen) step = std::max(step, positionStep(info, nodes[i]));
    for (int a = 0; a < 3; ++a) half = std::max(half, (info.bounds.max[a] - info.bounds.min[a]) * 0.5);
    SpzWriter spz(half + step);
    if (format == SplatFormat::Ply) {
        char comment[160];
        std::snprintf(comment, sizeof comment, "surfcast-export: set x, y, z = %.17g + x, %.17g + z, %.17g - y", origin.x, origin.y, origin.z);
        const std::string header = plyHeader(count, comment);
        if (std::fwrite(header.data(), 1, header.size(), f) != header.size()) return failed();
    }
    std::vector<uint8_t> records;
    for (size_t k = 0; k < chosen.size(); ++k) {
        const NodeRecord& n = nodes[chosen[k]];
        auto block = set.readBlock(n);
        if (!block) return block.status();
        SC_TRY(checkFiniteSurfels(set, n, *block));
        records.resize(block->size() * kPlyRecordBytes);
        for (size_t i = 0; i < block->size(); ++i) {
            const Gaussian g = surfelGaussian(set, n, *block, i, origin, options, axes);
            if (format == SplatFormat::Ply) plyRecord(g, records.data() + i * kPlyRecordBytes);
            else spz.add(g);
        }
        if (format == SplatFormat::Ply && std::fwrite(records.data(), 1, records.size(), f) != records.size()) return failed();
        report.splats += block->size();
        ++report.nodes;
        if (progress) progress(k + 1, chosen.size());
    }
    if (format == SplatFormat::Spz) {
        auto bytes = spz.finish();
        if (!bytes) return bytes.status();
        if (std::fwrite(bytes->data(), 1, bytes->size(), f) != bytes->size()) return failed();
    }
    return report;
}

}  // namespace surfcast
