// surfcast-build --preview: a small set published to the build's output
// folder before the build, for viewers to open and follow while it runs
// (docs/FORMAT.md, "preview"); the build's versions (refine.h) and then
// the set replace it as a build replaces any set.
#pragma once

#include <cstdint>

#include "octree_builder.h"

namespace surfcast {

// Unless options.output holds a set already (whose viewers keep it until the
// build replaces it; a preview or version that a killed build left is no such
// set), builds there a set of every Nth point of each input,
// marked as a preview and keeping no build record (it is replaced, never
// updated); of a LAZ file, the first point of each chunk, read with nothing
// decoded (openLasChunkStarts). N is guessed from the inputs' sizes (bytes per point by format),
// so no pass over the points comes first, and doubled while the sample would
// exceed 2 x `points`. The sample is read once and built from memory
// (textured meshes' textures are read again). Says what it did on stderr
// unless options.progress is off. Returns whether it wrote one.
Result<bool> publishPreview(const BuildOptions& options, uint64_t points);

}  // namespace surfcast
