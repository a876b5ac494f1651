// A tile set as a 3D Tiles 1.1 tileset (docs/EXPORT.md): tileset.json and
// one glb per node, so that CesiumJS and the other 3D Tiles engines stream
// the same level-of-detail tree Surfcast's clients do.
//
// - The octree maps to REPLACE refinement, one tile per node; a tile's
//   geometricError is its node's spacing h (the distance between its
//   samples: the error of drawing it instead of its children), leaves too
//   (their samples' error against the surface: engines size points by it).
// - Bounding volumes are boxes: the node's cube cut to the set's bounds,
//   grown by its position step (a quantized position may round past the
//   bounds) or, for splats, their reach, and by its descendants' growth, so
//   every child lies inside its parent.
// - Positions keep double precision where it matters: the root's transform
//   carries the set's centre, each glb's node its tile's centre (points:
//   its node's corner), and the numbers in the glb are offsets from that. glTF is y-up; 3D Tiles turns
//   it z-up (the set's own up) at load.
// - Points: each surfel a glTF point with NORMAL and COLOR_0 (linear, as
//   glTF defines it, 16 bits a channel, alpha its opacity), unlit; the
//   classification, intensity and return numbers, where the set has them,
//   as EXT_structural_metadata property attributes (class "surfel"), the
//   scalar attributes as a property table of it.
//   Positions are the block's own integers (KHR_mesh_quantization), and the
//   vertex data is compressed by meshoptimizer (EXT_meshopt_compression;
//   KHR_draco_mesh_compression does not allow points): bench/BENCHMARKS.md,
//   "3D Tiles export".
// - Splats: each surfel a flat Gaussian (gaussians.h) in
//   KHR_gaussian_splatting, compressed by SPZ
//   (KHR_gaussian_splatting_compression_spz_2), which CesiumJS requires of
//   3D Tiles splats; the LiDAR and scalar attributes as a property table
//   with a row per splat (EXT_mesh_features' implicit feature IDs):
//   CesiumJS reads every attribute of an SPZ primitive from the SPZ.
// - Metadata holds values, never the set's storage codes (docs/EXPORT.md,
//   "Metadata"): integers that are the values, a continuous scalar's
//   stored integer normalized with the property's offset and scale, or a
//   wide field's value as a double; the set's constants are tileset
//   metadata (class "set" of tileset.json's schema).
//
// Blocks are decoded one node at a time: memory holds one node, whatever
// the set's size. The folder is written beside the output and swapped in
// whole (folder_publish.h).
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "gaussians.h"
#include "tileset_reader.h"

namespace surfcast {

struct Tiles3dOptions {
    enum class As { Points, Splats } as = As::Splats;
    // Points: their vertex data compressed by meshoptimizer
    // (EXT_meshopt_compression: glTF's one compression for points, which
    // CesiumJS reads), or not. Splats are SPZ either way.
    enum class Compression { Meshopt, None } compression = Compression::Meshopt;
    // Every tile in tileset.json, or the tree as implicit-tiling subtree
    // files (tiles3d_implicit.h); Auto: implicit for sets of more than
    // 10,000 nodes.
    enum class Tiling { Auto, Explicit, Implicit } tiling = Tiling::Auto;
    GaussianOptions gaussians;  // splats
    // Told after each node: nodes written so far, of all.
    std::function<void(size_t, size_t)> progress;
};

struct Tiles3dReport {
    size_t tiles = 0;
    uint64_t points = 0;    // surfels written, over all tiles
    uint64_t bytes = 0;     // glb, tileset.json and subtree bytes
    bool implicit = false;  // the tree went into subtree files
};

// Writes `set` as a 3D Tiles tileset into the folder `output` (replacing a
// previous export there; refusing any other existing folder). Errors name
// the node whose block fails.
Result<Tiles3dReport> writeTiles3d(const TilesetReader& set, const Tiles3dOptions& options, const std::string& output);

// Whether `folder` holds a tileset.json that this export wrote (its asset's
// generator is surfcast-export).
bool isTiles3dExport(const std::string& folder);

}  // namespace surfcast
