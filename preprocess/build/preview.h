// surfcast-build --preview: a small set published to the build's output
// folder before the build, for viewers to open and follow while it runs
// (docs/FORMAT.md, "preview"); the build then replaces it as it replaces any
// set.
#pragma once

#include <cstdint>

#include "octree_builder.h"

namespace surfcast {

// Unless options.output holds a set already (whose viewers keep it until the
// build replaces it), builds there a set of every Nth point of each input,
// about `points` in all, marked as a preview and keeping no build record (it
// is replaced, never updated). N comes from the inputs' sizes (bytes per
// point guessed by format), so no pass over the points comes first; the
// sample is read once and built from memory. Says what it did on stderr
// unless options.progress is off.
Status publishPreview(const BuildOptions& options, uint64_t points);

}  // namespace surfcast
