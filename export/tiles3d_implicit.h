// 3D Tiles 1.1 implicit tiling of a set's octree (docs/EXPORT.md): the tree
// as subtree files instead of one tile object per node in tileset.json.
//
// A tile set's octree is a 3D Tiles implicit octree as it stands: node
// (level, x, y, z) is the implicit tile of the same coordinates in the root
// cube. Each subtree file holds `levels` levels: which of its tiles exist,
// which have content (nodes with surfels), which child subtrees exist, and
// every tile's own box and geometric error as tile metadata (the
// TILE_BOUNDING_BOX and TILE_GEOMETRIC_ERROR semantics), so an engine sees
// the same boxes and errors as in the explicit tileset.json.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "status.h"
#include "tileset_format.h"

namespace surfcast {

struct ImplicitTile {
    NodeKey key;
    bool content = false;           // the tile has a glb
    std::array<double, 12> box{};   // 3D Tiles box: centre, then three half-axis vectors
    double geometricError = 0;
};

// The id of the schema tileset.json declares: its class "tile" for the
// subtrees' tile metadata, "set" for the set's constants (tiles3d_export.h).
inline constexpr const char* kTilesetSchemaId = "surfcast_tiles";
// The schema, with its class "tile", for the subtrees' tile metadata.
nlohmann::json implicitTileSchema();

// The root tile's implicitTiling object for subtrees of `levels` levels
// over a tree of `availableLevels` levels, at subtrees/{level}-{x}-{y}-{z}.subtree.
nlohmann::json implicitTiling(int levels, int availableLevels);

// Writes the subtree files of `tiles` (every node of the tree, any order;
// every tile's parent among them) into `folder`/subtrees; returns the
// bytes written.
Result<uint64_t> writeImplicitSubtrees(const std::vector<ImplicitTile>& tiles, int levels, const std::string& folder);

}  // namespace surfcast
