// The set's points as an update holds them (update.cpp): decoded from its
// leaves, taken back to their inputs' lattices where they can be, and the
// added points that repeat the ones that stay decoded moved onto them.
#pragma once

#include <array>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <unordered_map>
#include <vector>

#include "build_context.h"
#include "sampler.h"
#include "surfel.h"
#include "tileset_reader.h"

namespace surfcast {

// An input's coordinate lattice (InputDescription::latticeScale).
struct Lattice {
    Vec3d scale, offset;
};

// A node's quantization as the builder holds its decoded positions: world
// positions less `origin`, each held inside the node's box [k e, (k + 1) e)
// relative to `origin`, so that it goes to its own chunk (a kept neighbour
// would drop it) and quantizes as before: one quantized to the node's upper
// face lies in the neighbour's box, and one on its lower face can round below
// it on the way from world coordinates. k e is exact (the root is aligned
// with the set's, `origin` a whole number of node edges from its minimum), as
// the chunks' cells, whole fractions of it, are.
class NodeGrid {
public:
    NodeGrid(const TilesetInfo& info, const NodeRecord& node, const Vec3d& origin)
        : info_(&info), node_(node), origin_(origin), min_(nodeMin(info, node.key)), step_(positionStep(info, node)),
          edge_(nodeEdge(info, node.key.level)), top_(double((uint64_t(1) << node.positionBits) - 1)) {
        lo_ = min_ - origin;
        for (int a = 0; a < 3; ++a) lo_[a] = std::round(lo_[a] / edge_) * edge_;
    }
    const NodeRecord& node() const { return node_; }
    // Quantized position q; with its input's `lattice`, the lattice point
    // that quantizes to q, where one does: the input's very coordinates, as
    // its reader gives them (las_reader.cpp: integer * scale + offset).
    Vec3d decoded(const uint32_t q[3], const Lattice* lattice = nullptr) const {
        Vec3d w = quantizedPosition(*info_, node_, q);
        if (lattice) {
            Vec3d raw;
            bool on = true;
            for (int a = 0; a < 3 && on; ++a) {
                const double k = std::round((w[a] - lattice->offset[a]) / lattice->scale[a]);
                raw[a] = k * lattice->scale[a] + lattice->offset[a];
                on = k >= INT32_MIN && k <= INT32_MAX && quantized(raw[a], a) == q[a];
            }
            if (on) w = raw;
        }
        Vec3d p = w - origin_;
        for (int a = 0; a < 3; ++a) p[a] = std::clamp(p[a], lo_[a], std::nextafter(lo_[a] + edge_, lo_[a]));
        return p;
    }
    // The quantized position of p (relative to `origin`) in the node: as
    // encodeNode quantizes it, but from world coordinates (a tie may round
    // the other way).
    std::array<uint32_t, 3> quantize(const Vec3d& p) const {
        return {quantized(p.x + origin_.x, 0), quantized(p.y + origin_.y, 1), quantized(p.z + origin_.z, 2)};
    }

private:
    uint32_t quantized(double world, int a) const { return uint32_t(std::clamp(std::round((world - min_[a]) / step_), 0.0, top_)); }

    const TilesetInfo* info_;
    NodeRecord node_;
    Vec3d origin_, min_, lo_;
    double step_, edge_, top_;
};

// A decoded block's surfels as the builder holds them (positions relative to
// the root minimum as NodeGrid holds them, each on its input's `lattices`
// where given, colours in 16 bits, LiDAR values as read, the stored scalar
// fields as rows of `table`), with orientation rules `rules`.
void appendSurfels(const BuildContext& c, const TilesetReader& set, const NodeRecord& node, const BlockData& block,
                   const std::vector<uint16_t>& rules, std::span<const Lattice* const> lattices, std::vector<Surfel>* out,
                   ScalarTable* table);

// Each surfel's input (the provenance attribute; 0 where the set has none).
std::vector<uint32_t> inputsOf(const BlockData& block);

// The set's leaf points that stay decoded (Update::latticeOf), to move an
// added point that quantizes to one of their positions onto it: a repeat of
// the set's point then meets it, and buildSubtree keeps one of the two, as a
// fresh build keeps one of exact duplicates. (A distinct added point within
// the leaf's step of such a point meets it too, where a fresh build keeps
// both; any other added point keeps its position.)
class SetLeaves {
public:
    // `decoded`: whether leaf n's points of an input stay decoded; `removed`:
    // the inputs whose points go (no added point is moved onto those).
    SetLeaves(const TilesetReader& set, const Vec3d& origin, std::function<bool(const NodeRecord&, uint32_t)> decoded,
              std::vector<uint32_t> removed)
        : set_(set), info_(set.info()), origin_(origin), shift_(origin - set.info().rootMin), decoded_(std::move(decoded)),
          removed_(std::move(removed)) {
        for (const NodeRecord& n : set.nodes()) nodes_[n.key] = &n;
    }
    // Moves the added points that quantize to a held position onto it.
    Status snap(std::span<Surfel> points);

private:
    // The key at `level` of position p relative to the root minimum (what
    // the builder's halving splits give it, but on a split's very plane).
    std::optional<NodeKey> keyAt(const Vec3d& p, int level) const {
        const double e = nodeEdge(info_, level), cells = std::ldexp(1.0, level);
        NodeKey k{uint8_t(level)};
        for (int a = 0; a < 3; ++a) {
            const double i = std::floor(p[a] / e);
            if (!(i >= 0 && i < cells)) return std::nullopt;
            (a == 0 ? k.x : a == 1 ? k.y : k.z) = uint32_t(i);
        }
        return k;
    }
    const NodeRecord* find(const Vec3d& p) const {
        for (int level = 0; level <= kMaxLevel; ++level) {
            const auto key = keyAt(p, level);
            if (!key) return nullptr;
            const auto it = nodes_.find(*key);
            if (it == nodes_.end()) return nullptr;
            if (it->second->flags & kFlagInputPoints) return it->second;
        }
        return nullptr;
    }

    struct Leaf {
        NodeGrid grid;
        std::vector<std::array<uint32_t, 3>> held;  // its decoded points' quantized positions, sorted
    };
    const TilesetReader& set_;
    const TilesetInfo& info_;
    Vec3d origin_, shift_;  // shift_: from positions relative to `origin` to ones relative to the set's root
    std::function<bool(const NodeRecord&, uint32_t)> decoded_;
    std::vector<uint32_t> removed_;
    std::unordered_map<NodeKey, const NodeRecord*, NodeKeyHash> nodes_;
    std::map<NodeKey, Leaf> leaves_;  // the leaves added points reached, kept for every pass over them
    Leaf* last_ = nullptr;
};

}  // namespace surfcast
