// The set's points as an update holds them (set_points.h).
#include "set_points.h"

#include <algorithm>
#include <cmath>

namespace surfcast {

void appendSurfels(const BuildContext& c, const TilesetReader& set, const NodeRecord& node, const BlockData& block,
                   const std::vector<uint16_t>& rules, std::span<const Lattice* const> lattices, std::vector<Surfel>* out,
                   ScalarTable* table) {
    const TilesetInfo& info = set.info();
    const AttributeInfo* intensity = info.attribute(kLidarAttributes[kLidarIntensity]);
    const NodeGrid grid(info, node, c.rootMin());
    for (size_t i = 0; i < block.size(); ++i) {
        Surfel s;
        s.position = grid.decoded(&block.positions[3 * i], lattices.empty() ? nullptr : lattices[i]);
        s.normal = Vec3f{block.normals[3 * i], block.normals[3 * i + 1], block.normals[3 * i + 2]};
        if (!block.colors.empty())
            for (int k = 0; k < 3; ++k) s.color[k] = info.colorBits == 8 ? uint16_t(block.colors[3 * i + k] * 257) : block.colors[3 * i + k];
        s.source = rules[i];
        s.fromSet = node.flags & kFlagInputPoints;
        // The stored intensity is (value - offset) / scale: its value again
        // stores as the same integer (the top step's value can pass 65535,
        // which the clamp of storedIntensity also maps to the top).
        if (!block.intensity.empty() && intensity)
            s.intensity = uint16_t(std::clamp(std::lround(block.intensity[i] * intensity->scale + intensity->offset), 0l, 65535l));
        if (!block.classification.empty()) s.classification = block.classification[i];
        s.returns = uint8_t((block.returnNumber.empty() ? 0 : block.returnNumber[i] & 15) |
                            (block.numberOfReturns.empty() ? 0 : block.numberOfReturns[i] << 4));
        if (!block.opacity.empty()) s.alpha = block.opacity[i];
        if (table) {
            std::vector<uint32_t> row(table->fields());
            for (size_t f = 0; f < row.size() && f < block.scalars.size(); ++f) row[f] = block.scalars[f].values[i];
            s.row = table->append(row.data());
        }
        out->push_back(s);
    }
}

std::vector<uint32_t> inputsOf(const BlockData& block) {
    std::vector<uint32_t> of(block.size(), 0);
    for (const ScalarAttribute& a : block.scalars)
        if (a.name == kProvenanceAttribute) of = a.values;
    return of;
}

Status SetLeaves::snap(std::span<Surfel> points) {
    for (Surfel& s : points) {
        const Vec3d p = s.position + shift_;
        // Points come in scan order: most lie in the leaf of the one before.
        if (!last_ || keyAt(p, last_->grid.node().key.level) != last_->grid.node().key) {
            const NodeRecord* leaf = find(p);
            last_ = nullptr;
            if (!leaf) continue;
            auto it = leaves_.find(leaf->key);
            if (it == leaves_.end()) {
                Leaf l{NodeGrid(info_, *leaf, origin_), {}};
                auto block = set_.readBlock(*leaf, true);
                if (!block) return block.status();
                const std::vector<uint32_t> of = inputsOf(*block);
                for (size_t i = 0; i < block->size(); ++i)
                    if (decoded_(*leaf, of[i]) && std::find(removed_.begin(), removed_.end(), of[i]) == removed_.end())
                        l.held.push_back({block->positions[3 * i], block->positions[3 * i + 1], block->positions[3 * i + 2]});
                std::sort(l.held.begin(), l.held.end());
                it = leaves_.emplace(leaf->key, std::move(l)).first;
            }
            last_ = &it->second;
        }
        const auto q = last_->grid.quantize(s.position);
        if (std::binary_search(last_->held.begin(), last_->held.end(), q)) s.position = last_->grid.decoded(q.data());
    }
    return {};
}

}  // namespace surfcast
