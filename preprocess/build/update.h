// Updates in place (docs/FORMAT.md, "Updates in place"): scans added to a
// published set, rebuilding only the chunks the new points reach (their own
// points and their halos) and the levels above the chunks. Every other node
// keeps its block, its byte range and so its ETag; the new blocks are appended
// to blocks.bin and the new hierarchy switched in with tileset.json.
#pragma once

#include <string>
#include <vector>

#include "octree_builder.h"
#include "stages.h"

namespace surfcast {

// `options`: the set's build options (from its build record) with the added
// inputs after its own, `threads` and `progress` as the update asks;
// `added`: how many of options.inputs.paths are new (the last ones); `set`:
// the set's folder; `record`: the set's build record, `commandLine` the one
// the updated set's record keeps. Fails, leaving the set as it was, where the
// added points change a decision the kept blocks depend on (the root cube,
// the colour depth, an attribute's quantization) or where the set was built
// with textured meshes or captured weights.
Result<BuildSummary> updateTileset(const BuildOptions& options, size_t added, const std::string& set, const BuildPlan& record,
                                   const std::vector<std::string>& commandLine);

}  // namespace surfcast
