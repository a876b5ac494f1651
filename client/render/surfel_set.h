// The surfels one frame draws, in the layout the GPU reads (GpuSurfel), with a
// double-precision render origin. Both renderers (GPU and CPU reference) take
// the same SurfelSet, so they see identical inputs.
#pragma once

#include <string>
#include <vector>

#include "coloring.h"
#include "gpu_types.h"
#include "tileset_reader.h"
#include "tileset_format.h"
#include "status.h"
#include "tile_source.h"
#include "vec3.h"

namespace surfcast {

struct SurfelSet {
    Vec3d origin;                           // world position of local (0,0,0)
    std::vector<gpu_types::GpuSurfel> surfels;
    Box3d bounds;                           // world bounds of the surfel centres
    bool hasWeights = false;                // s_k came from the tile set
    bool hasColor = false;                  // colours show measured appearance (RGB, intensity): drawn unlit
    double kernelScale = kDefaultKernelScale;  // the k its weights assume (tileset.json kernel_scale)
    bool normalsOriented = false;           // normalsOriented(tileset.json normal_source)
    bool translucent = false;               // some surfel's opacity is under 1 (the set stores opacity)
    Coloring coloring;                      // what appendNode colours by (resolved, never Auto) and hides
    TilesetStatistics statistics;           // the set's ranges, for the colour ramps
};

// Which nodes of a tile set to draw: a level (its nodes plus the leaves above
// it, which together cover the surface), or every leaf (level < 0).
struct LevelChoice {
    int level = -1;
};

// `tilesetDir` is a folder or an http(s) URL (tile_source.h; `http` says how
// to reach it). A URL's nodes are fetched whole, one range each; more
// surfels than `gpuBudget` bytes hold (32 each; 0: 1 GiB) is an error that
// names --lod, which streams only what a view needs. `info`, if given, gets
// the set's tileset.json as read.
Result<SurfelSet> loadSurfelSet(const std::string& tilesetDir, const LevelChoice& choice, const Coloring& coloring = {},
                                const HttpOptions& http = {}, size_t gpuBudget = 0, TilesetInfo* info = nullptr);

// An empty set for a tile set (origin, flags and kernel scale from its
// tileset.json), and one decoded node's surfels appended to it, coloured and
// filtered by `coloring` (a mode the set cannot show falls back to Auto; check
// it first with resolveColorBy).
SurfelSet emptySurfelSet(const TilesetInfo& info, const Coloring& coloring = {});
void appendNode(SurfelSet& set, const TilesetInfo& info, const NodeRecord& node, const BlockData& block);
// What appendNode's surfels depend on besides the node's record and block:
// two versions of a set with equal keys decode a node with equal records and
// blocks to the same surfels (a follower then draws the old copy:
// surfcast_client.h). The origin, the root cube, the colour bits, the
// weights and attributes a block holds, and the colouring with what it reads
// (the intensity's scale and 2-98 % range, the elevation range).
std::string decodingKey(const TilesetInfo& info, const Coloring& coloring);
// The record fields appendNode and the block's decoding read, equal.
bool sameDecoding(const NodeRecord& a, const NodeRecord& b);

// Append one surfel given in world coordinates (origin must be set first).
// Colour components and opacity in [0, 1]; an opacity under 1 marks the set
// translucent. Non-finite input is kept: the renderers guard it.
void addSurfel(SurfelSet& set, const Vec3d& position, const Vec3f& normal, float radius,
               const Vec3f& color, float weight = 1.f, uint32_t edge = 0, float opacity = 1.f);

// Reorder along a Morton (Z-order) curve over the bounds: rasterizers with tiled
// caches (lavapipe measured 1.3-3.9x) run faster on spatially coherent input.
// Returns the permutation: sorted index -> index before sorting.
std::vector<uint32_t> sortMorton(SurfelSet& set);

// The frameBox direction from which most surfels face the eye, where their
// normals are oriented and backfaces culled: a scan in its sensor's frame (z
// forward, y down) would show its backs from the usual direction. The usual
// one (0) unless another sees more than 1.25 times as many. Measured ratios
// of the best to the usual: the closed bunny 1.09, milk_cartoon 1.18 (its
// usual view is right), table_scene_mug 1.37 (whose usual view shows 21 % of
// what it shows unculled), fragment 6.5.
int frontDirection(const SurfelSet& set);

// Packing shared with GLSL's unpack functions.
uint32_t packNormalOct(const Vec3f& n);
Vec3f unpackNormalOct(uint32_t packed);
uint32_t packColor(const Vec3f& rgb, float a = 1.f);
Vec3f unpackColor(uint32_t packed);
// Edge-weight ratios (+s, -s, +t, -t) as GpuSurfel::edge; clamped to
// [1/255, 1] * SC_EDGE_RATIO_MAX so that a packed value is never 0 ("none").
uint32_t packEdgeWeights(const float ratios[4]);

// A unit tangent of n, the twin of GLSL tangentOf (splat_common.glsl): the
// edge weights' directions are defined in this basis of the world normal.
Vec3f tangentOf(const Vec3f& n);

}  // namespace surfcast
