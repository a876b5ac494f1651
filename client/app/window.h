// surfcast-view's window (GLFW): orbit and fly camera, mode keys, screenshots,
// the frame time in the title. Never used by the headless path (GLFW needs a
// display; DESIGN.md, Platform facts).
#pragma once

#include "view_options.h"

namespace surfcast {

// Draws `set`, loaded from the tile set `info` describes (its colour keys);
// with --lod, streams options.set through a SurfcastClient instead (level of
// detail per frame; `set` and `info` are unused) and --frames counts only
// frames whose view has converged.
int runWindow(const ViewOptions& options, const SurfelSet& set, const TilesetInfo& info);

}  // namespace surfcast
