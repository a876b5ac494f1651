// surfcast-view: renders a tile set in a window or headless. main() only
// parses arguments, loads the surfels and hands over to one of the two.
#include <cstdio>

#include "headless.h"
#include "view_options.h"
#include "window.h"

int main(int argc, char** argv) {
    surfcast::ViewOptions options;
    int exitCode = 0;
    if (!surfcast::parseViewOptions(argc, argv, &options, &exitCode)) return exitCode;
    if (options.lod) {
        if (options.settings.mode == surfcast::RenderMode::CpuReference) {
            std::fprintf(stderr, "surfcast-view: --lod renders with a GPU mode\n");
            return 2;
        }
        if (options.headless) return surfcast::runHeadlessLod(options);
        return surfcast::runWindow(options, surfcast::SurfelSet{}, surfcast::TilesetInfo{});
    }
    surfcast::TilesetInfo info;
    auto set = surfcast::loadSurfelSet(options.set, options.level, options.client.coloring, options.client.http,
                                       options.client.gpuBudget, &info);
    if (!set) {
        std::fprintf(stderr, "surfcast-view: %s\n", set.status().message().c_str());
        return 1;
    }
    if (options.color)
        for (auto& s : set->surfels) s.color = surfcast::packColor(*options.color);
    options.settings = surfcast::effectiveSettings(options, surfcast::settingsForSet(set->kernelScale, set->hasColor, set->normalsOriented, set->translucent));
    if (options.settings.mode == surfcast::RenderMode::EwaSurfel && !set->hasWeights)
        std::fprintf(stderr, "surfcast-view: warning: %s has no normalization weights; ewa-surfel draws every surfel at "
                             "weight 1 (build with --weights analytic, or run surfcast-weights on the set)\n",
                     options.set.c_str());
    return options.headless ? surfcast::runHeadless(options, *set) : surfcast::runWindow(options, *set, info);
}
