// A set's surfels as Gaussians (gaussians.h): the one surfel's Gaussian the
// 3D Tiles splats and the splat files share, and the splat files, one cut
// through the tree each (docs/EXPORT.md, "Splat files").
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <optional>
#include <string>

#include "camera.h"
#include "gaussians.h"
#include "tileset_reader.h"

namespace surfcast {

// The axes a splat format keeps, from the set's own (z up): glTF's and
// SPZ's y up (x, z, -y), or the 3D Gaussian splatting PLY's y down (x, -z, y),
// the camera frame its scenes are trained in. Both are rotations.
enum class SplatAxes { YUp, YDown };
Vec3d toSplatAxes(const Vec3d& v, SplatAxes axes);

// Whether a decoded block's normals and radii are finite numbers, as
// Gaussians need (a block's floats are not range-checked when decoded):
// an error naming the node if not.
Status checkFiniteSurfels(const TilesetReader& set, const NodeRecord& node, const BlockData& block);

// Surfel i of a node's decoded block as a Gaussian about `centre` (world).
Gaussian surfelGaussian(const TilesetReader& set, const NodeRecord& node, const BlockData& block, size_t i, const Vec3d& centre,
                        const GaussianOptions& options, SplatAxes axes);

// Which nodes a splat file holds: those of `level` and the leaves above it,
// as surfcast-view --level draws; the leaves alone (level -1, the default);
// or, with a budget, the deepest such level whose nodes hold at most
// `budget` surfels (at least the root). With a camera: the nodes
// surfcast-view --lod draws for that view at width x height (culled to the
// view, refined while a node's projected spacing exceeds `lodPixels`, within
// `budget` surfels if one is given).
struct SplatCut {
    int level = -1;
    uint64_t budget = 0;
    std::optional<Camera> camera;
    int width = 1280, height = 720;
    double lodPixels = 1.0;
};

enum class SplatFormat { Ply, Spz };

struct SplatFileReport {
    uint64_t splats = 0;
    size_t nodes = 0;
    std::string cut;  // "level N", "leaves" or "the camera's view"
};

// Writes the cut's surfels to `f` as PLY (streamed, one node at a time) or
// SPZ (19 bytes a surfel held, then compressed), node by node in key order
// (level, then x, y, z), each node's surfels in block order, about the
// centre of the set's bounds, which the PLY's comment records. `progress`:
// nodes done, of all.
Result<SplatFileReport> writeSplatFile(const TilesetReader& set, SplatFormat format, const SplatCut& cut, const GaussianOptions& options,
                                       std::FILE* f, const std::function<void(size_t, size_t)>& progress = {});

}  // namespace surfcast
