// surfcast-view's window (GLFW): orbit and fly camera, mode keys, screenshots,
// the frame time in the title. Never used by the headless path (GLFW needs a
// display; DESIGN.md, Platform facts).
#pragma once

#include "view_options.h"

namespace surfcast {

class StreamingSet;

// Draws `set`; with `stream`, draws what the stream has resident for each
// frame's view instead (level of detail, --lod), and --frames counts only
// once the view has converged.
int runWindow(const ViewOptions& options, const SurfelSet& set, StreamingSet* stream = nullptr);

}  // namespace surfcast
