#include "preview.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "inputs.h"

namespace surfcast {

Status publishPreview(const BuildOptions& options, uint64_t points) {
    const std::string& out = options.output;
    if (std::filesystem::exists(std::filesystem::path(out) / "tileset.json")) {
        if (options.progress)
            std::fprintf(stderr, "preview: %s holds a set, which its viewers keep until the build replaces it: none written\n",
                         out.c_str());
        return {};
    }
    double estimate = options.inputs.defaultScene ? double(options.inputs.scene.targetPoints) : 0;
    for (const std::string& path : options.inputs.paths) {
        std::error_code ec;
        const double bytes = double(std::filesystem::file_size(path, ec));
        if (ec) continue;  // a URL or an object: the build reads and checks it
        const std::string ext = lowerExtension(path);
        estimate += bytes / (ext == ".laz" ? 8 : ext == ".las" ? 28 : 24);
    }
    BuildOptions p = options;
    p.commandLine.clear();
    p.preview = uint32_t(std::clamp(estimate / double(std::max<uint64_t>(1, points)), 1.0, 1e9));
    p.progress = false;
    const auto start = std::chrono::steady_clock::now();
    InputOptions sampling = p.inputs;
    sampling.stride = p.preview;
    auto captured = captureInputs(sampling);
    if (!captured) return captured.status();
    p.inputs.captured = std::move(*captured);
    auto summary = buildTileset(p);
    if (!summary) return summary.status();
    if (options.progress)
        std::fprintf(stderr, "preview: %s, every %u%s point of each input, in %.2f s\n", out.c_str(), p.preview,
                     p.preview == 1 ? "" : "th", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    return {};
}

}  // namespace surfcast
