// A node as the chunk and merge stages build it, and what both do to a
// finished level: colour its textured surfels and encode its blocks.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "build_context.h"
#include "level_attributes.h"
#include "tileset_format.h"

namespace surfcast {

struct BuiltNode {
    NodeKey key;
    std::vector<Surfel> surfels;
    uint8_t childMask = 0;
    bool inputPoints = false;
    double cell = 0;  // the cell of the grid a resampled node was sampled on (BuildContext::nodeGrid); 0 for leaves
    LevelNode level;
};

// The largest cell any of `nodes` (of one level) was sampled on, at least the
// level's G³ cell: the fallback h of a node with no neighbours at all.
double largestCell(const BuildContext& context, int level, std::span<BuiltNode* const> nodes);

// The colours of one level's surfels from textured meshes (--texture-filter
// ewa or optimal), once the level's h (and radii) are known; `halo`: the
// level's surfels beyond these nodes (other chunks). Returns the optimal
// filter's solves.
FitReport filterLevelTextures(const BuildContext& context, std::span<BuiltNode* const> nodes, std::span<const Surfel> halo,
                              int threads, StepTimes& steps);

// The record of a node an update keeps (KeepNode): its key, children and
// surfel count, and no block.
NodeRecord keptRecord(const BuiltNode& node);

// The node's hierarchy record (its block's offset, size and CRC left for the
// writer) and Draco block.
struct EncodedNode {
    NodeRecord record;
    std::vector<uint8_t> blob;
};
Result<EncodedNode> encodeNode(const BuildContext& context, const BuiltNode& node, const ScalarTable& scalars, StepTimes& steps);

}  // namespace surfcast
