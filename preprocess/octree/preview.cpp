#include "preview.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "build_context.h"
#include "inputs.h"

namespace surfcast {

Result<bool> publishPreview(const BuildOptions& options, uint64_t points) {
    const std::string& out = options.output;
    const std::string json = out + "/tileset.json";
    std::error_code ec;
    if (std::filesystem::exists(json, ec)) {
        // A finished set stays; a preview or version a killed build left is replaced.
        std::ifstream in(json, std::ios::binary);
        auto there = readTilesetJson(std::string{std::istreambuf_iterator<char>(in), {}}, json);
        if (!there || there->previewStride == 0) {
            if (options.progress)
                std::fprintf(stderr, "preview: %s holds a set, which its viewers keep until the build replaces it: none written\n",
                             out.c_str());
            return false;
        }
    }
    // The stride guessed from the files' sizes (bytes per point by format);
    // captureInputs doubles it where the guess holds too many points.
    double estimate = options.inputs.defaultScene ? double(options.inputs.scene.targetPoints) : 0;
    for (const std::string& path : options.inputs.paths) {
        std::error_code ec;
        const double bytes = double(std::filesystem::file_size(path, ec));
        if (ec) continue;  // a URL or an object: captureInputs bounds what it holds
        const std::string ext = lowerExtension(path);
        if (ext != ".laz") estimate += bytes / (ext == ".las" ? 28 : 24);  // LAZ: its chunk starts
    }
    points = std::max<uint64_t>(1, points);
    BuildOptions p = normalizeOptions(options);  // the attributes and threads the build's own reading uses
    p.commandLine.clear();
    p.progress = false;
    const auto start = std::chrono::steady_clock::now();
    p.inputs.chunkStarts = true;
    auto captured = captureInputs(p.inputs, uint32_t(std::clamp(estimate / double(points), 1.0, 1e9)), 2 * points);
    p.inputs.chunkStarts = false;
    if (!captured) return captured.status();
    p.inputs.captured = std::move(captured->inputs);
    p.preview = captured->stride;
    auto summary = buildTileset(p);
    if (!summary) return summary.status();
    if (options.progress)
        std::fprintf(stderr, "preview: %s, 1 in %u points of each input (%llu), in %.2f s\n", out.c_str(), p.preview,
                     (unsigned long long)summary->inputPoints,
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    return true;
}

}  // namespace surfcast
