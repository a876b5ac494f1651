// surfcast-view's command line.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "camera.h"
#include "render_settings.h"
#include "surfcast_client.h"
#include "splat_renderer.h"
#include "surfel_set.h"

namespace surfcast {

struct ViewOptions {
    std::string set;                  // tile set folder
    bool headless = false;
    std::vector<Camera> cameras;      // empty: frame the whole set
    int width = 1280, height = 720;
    std::string out = "frame.png";
    LevelChoice level;
    RenderSettings settings;
    bool shadingGiven = false;        // else unlit with colour, lambert without
    bool backfaceCullGiven = false;   // else on where the set's normals are oriented
    bool edgeAAGiven = false;         // else the set's default (settingsForSet)
    bool kernelScaleGiven = false;    // else the set's kernel_scale
    std::optional<Vec3f> color;       // draw every surfel in this colour (measurements)
    RendererOptions renderer;
    std::string device;
    bool validation = false;
    int repeat = 1;                   // headless: renders per frame (median times reported)
    std::optional<double> lod;        // level of detail: target projected spacing, pixels
    ClientOptions client;             // with --lod: culling, budgets, connections
    double maxWait = 120;             // with --lod: seconds a frame may stream before it is written
    bool saveRedraws = false;         // with --lod: also write every redraw (PATH_rNNN.png)
    int frames = 0;                   // window: quit after this many frames (0: run until closed)
    std::string screenshot;           // window: save the last frame here on exit
};

// Parses argv; on --help/--list-devices prints and sets *exitCode = 0; on a
// usage error prints it and sets *exitCode = 2. Returns false in both cases.
bool parseViewOptions(int argc, char** argv, ViewOptions* options, int* exitCode);

// The command line's settings, with the set's defaults (settingsForSet) for
// the kernel scale and shading where they were not given.
RenderSettings effectiveSettings(const ViewOptions& options, const RenderSettings& setDefaults);

// "name_0003.png" for frame 3 of several; the path itself for a single frame.
std::string framePath(const std::string& out, size_t frame, size_t frames);

// Prints "surfcast-view: <message>" to stderr; returns 1, the exit code.
int viewError(const std::string& message);

}  // namespace surfcast
