// Per-surfel normalization weights captured by rendering, after Ren et al.
// 2002, §7.2: each level is rendered without the low-pass filter and without
// normalization from viewpoints spread uniformly over a bounding sphere; the
// sum of weights S and the visibility depth are read back; a surfel visible at
// its centre gets the sample 1/S; its weight is the median of its samples.
#pragma once

#include <vector>

#include "context.h"
#include "tileset_reader.h"

namespace surfcast {

struct CaptureOptions {
    int views = 32;        // viewpoints on the bounding sphere (Fibonacci lattice)
    int size = 1024;       // capture image edge, pixels
    float zt = 0.5f;       // visibility offset, as RenderSettings::zt
    float cutoff = 1.f;    // kernel cutoff c (as when rendering)
    bool progress = true;  // a line per level on stderr
};

struct CaptureStats {
    size_t surfels = 0;
    size_t seen = 0;          // surfels with at least one sample
    size_t renders = 0;
    double seconds = 0;
};

// Weights for every node of `reader` (in reader.nodes() order), from the
// decoded `blocks` (same order). Surfels no view saw keep their stored weight
// when the set has one, else get the mean captured weight of their node (1
// when the node was never seen).
Result<std::vector<std::vector<float>>> captureWeights(gpu::Context& ctx, const TilesetReader& reader,
                                                       const std::vector<BlockData>& blocks, const CaptureOptions& options,
                                                       CaptureStats* stats);

}  // namespace surfcast
