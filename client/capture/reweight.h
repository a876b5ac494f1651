// Recompute the normalization weights of an existing tile set in place:
// decode every block, replace (or drop) the weight attribute, re-encode and
// write the set anew through TilesetWriter (atomic: readers see the old set or
// the new one, never a mix). Positions, colours and radii re-encode losslessly
// (same quantization); normals are re-quantized on the same 10-bit grid.
#pragma once

#include <string>

#include "weight_capture.h"

namespace surfcast {

enum class WeightMethod { Capture, None };

struct ReweightOptions {
    WeightMethod method = WeightMethod::Capture;
    CaptureOptions capture;
    std::string device;       // Vulkan device (see gpu::ContextOptions)
    bool validation = false;
};

struct ReweightSummary {
    CaptureStats capture;
    size_t nodes = 0;
    uint64_t blocksBytes = 0;
    double seconds = 0;
    std::string text() const;
};

Result<ReweightSummary> reweightTileset(const std::string& dir, const ReweightOptions& options);

}  // namespace surfcast
