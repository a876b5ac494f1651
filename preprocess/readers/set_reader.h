// A tile set as an input (surfcast-build --merge, or SET/tileset.json given
// as an input): its input points, the leaves' surfels (the nodes flagged
// kFlagInputPoints), decoded in hierarchy order, with their normals, colours,
// LiDAR attributes, opacity and the scalar fields `scalars` selects. The
// set's own provenance attribute is not a field: the build that reads the set
// gives its points their own. A local folder, or a prefix in an object store.
#pragma once

#include <memory>
#include <string>

#include "input_point.h"

namespace surfcast {

// `path`: the set's tileset.json (FOLDER/tileset.json, s3://BUCKET/PREFIX/tileset.json). Its points' normals are the set's (as if
// the input carried them); their precision, the coarsest step its leaves'
// positions are quantized to (at most its inputs' own step).
Result<std::unique_ptr<PointReader>> openSetReader(const std::string& path, const ScalarSelection& scalars = {});

// Whether `path` names a tile set's tileset.json (by its file name).
bool isSetInput(const std::string& path);
// An input's name (tileset.json's inputs): a tile set's folder name, another
// input's file name.
std::string inputName(const std::string& path);

}  // namespace surfcast
