// surfcast-view --headless: render frames to PNG, one JSON line per frame.
#pragma once

#include "view_options.h"

namespace surfcast {

// Returns the process exit status.
int runHeadless(const ViewOptions& options, const SurfelSet& set);
// With --lod: per frame, the nodes LodSelector picks (a local set: all resident).
int runHeadlessLod(const ViewOptions& options);

}  // namespace surfcast
