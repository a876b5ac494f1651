// Which nodes of a tile set to draw for a view (Ren et al. 2002, §6.2): a
// traversal from the root every frame with frustum culling of node boxes
// (expanded by the splat extent), backface culling by the nodes' visibility
// cones, and level choice by warping the node's box to the screen: a node is
// refined while its surfels' projected spacing, h times the largest
// pixels-per-unit over the box's corners, exceeds the target. Replacement
// refinement: children are drawn only when every child that is needed is
// resident, otherwise the node itself, so nothing holes while data streams.
// Refinement goes coarsest gap first (largest projected spacing, weighted
// towards the view centre) and stops at a splat budget and a memory budget,
// so a view that would need more than a frame can draw or the GPU can hold
// degrades evenly instead of refining one corner. The tree may be known in
// part (hierarchy pages fetched as traversal reaches them): a node whose
// children are in a page not yet added is drawn meanwhile, and the page is
// reported missing like a node.
// Cones cull only where the set's normals are oriented (normalsOriented):
// elsewhere a cone may point away from a surface the eye sees.
// Pure CPU, no Vulkan, no I/O: the streaming client and surfcast-view use it.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <unordered_map>
#include <vector>

#include "camera.h"
#include "tileset_format.h"

namespace surfcast {

struct LodParams {
    double targetPixels = 1.0;  // refine while the projected spacing exceeds this
    bool frustumCulling = true;
    bool backfaceCulling = true;  // by the nodes' visibility cones, where the normals are oriented
    // Nodes whose box misses the clip box (world coordinates) are culled:
    // none of their surfels would be drawn (RenderSettings::clip; up to the
    // float rounding of a surfel on the node's face).
    std::optional<Box3d> clip;
    size_t splatBudget = SIZE_MAX;  // most surfels drawn per frame (the root is drawn regardless)
    // Most bytes the nodes a view uses may occupy: those drawn, the ancestors
    // refined through and the children waited for, each at its surfel count
    // rounded up to `granule` times 32 bytes. A cache of this size can then
    // always hold what the view needs (the streamer sets these).
    size_t memoryBudget = SIZE_MAX;
    size_t granule = 1;
};

// Bytes a node occupies when resident: its surfels, 32 bytes each (GpuSurfel),
// in whole granules.
inline size_t residentBytes(uint32_t surfels, size_t granule) {
    granule = granule ? granule : 1;
    return (surfels + granule - 1) / granule * granule * 32;
}

struct LodStats {
    size_t visited = 0, frustumCulled = 0, backfaceCulled = 0, clipCulled = 0;
    size_t waiting = 0;  // nodes drawn in place of children that are not resident yet
    size_t budgetLimited = 0;  // nodes left coarser than the target by the splat or memory budget
    size_t splats = 0;         // surfels of the selected nodes
    // Nodes the view needs that are not resident, with a priority (the
    // projected spacing of the node waiting for them, weighted towards the
    // view centre: coarsest gaps first).
    std::vector<std::pair<uint32_t, double>> missing;
    // Hierarchy pages the view needs that are not added yet, as (the node
    // whose children the page holds, priority): the node's childPage says which.
    std::vector<std::pair<uint32_t, double>> missingPages;
    // Every resident node the view relies on: drawn, refined through, or a
    // child waiting for its siblings. A cache must not evict these.
    std::vector<uint32_t> used;
};

struct SelectedNode {
    uint32_t index;            // into the node list
    double projectedSpacing;   // pixels
};

class LodSelector {
public:
    // `nodes` in any order, one tree rooted at level 0 (readHierarchy's
    // output), or its top: page 0 (readHierarchyPage's).
    LodSelector(const TilesetInfo& info, std::vector<NodeRecord> nodes);
    // The records of a further page (readHierarchyPage's output, which leaves
    // out the page's first record: its proxy is here already). They get the
    // next indices; earlier indices stay.
    void addNodes(const std::vector<NodeRecord>& nodes);

    const std::vector<NodeRecord>& nodes() const { return nodes_; }

    // Nodes to draw for the camera at width x height pixels. `resident(i)`
    // says whether node i's surfels can be drawn now (all true for a local set).
    std::vector<SelectedNode> select(const Camera& camera, int width, int height, const LodParams& params,
                                     const std::function<bool(uint32_t)>& resident, LodStats* stats = nullptr) const;

    // The index of the node with this key, if it is known.
    std::optional<uint32_t> find(const NodeKey& key) const {
        auto it = index_.find(key);
        return it == index_.end() ? std::nullopt : std::optional(uint32_t(it->second));
    }

    // World box of node i (its octree cell, without the splat extent).
    Box3d box(uint32_t i) const;

private:
    TilesetInfo info_;
    std::vector<NodeRecord> nodes_;
    std::vector<std::array<int32_t, 8>> children_;  // node index per child slot, -1 if none (or not added yet)
    std::unordered_map<NodeKey, int32_t, NodeKeyHash> index_;
    int32_t root_ = -1;
};

}  // namespace surfcast
