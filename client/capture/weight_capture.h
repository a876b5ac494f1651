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
    bool edgeWeights = true;  // capture Ren's per-vertex weights at edges (4 x 8 bits per surfel
                              // in the nodes that have edge surfels)
    bool progress = true;  // a line per level on stderr
};

struct CaptureStats {
    size_t surfels = 0;
    size_t seen = 0;          // surfels with at least one sample
    size_t edges = 0;         // surfels given edge weights
    size_t renders = 0;
    double seconds = 0;
};

// Per node (in reader.nodes() order): the weights s_k, and the edge-weight
// ratios (4 per surfel, BlockData::edgeWeights) or nothing when no surfel of
// the node is at an edge.
struct CapturedWeights {
    std::vector<std::vector<float>> weights;
    std::vector<std::vector<float>> edgeWeights;
};

// A surfel is at an edge (and its node stores edge weights) when the weight
// captured at one of its tangent points exceeds s_k by this factor: toward a
// boundary S falls and the ratio climbs to 2-4. Irregular interior sampling
// moves ratios by about +-30% too; treating that as edges made interiors worse
// (bunny, magnified, mean error 0.111 -> 0.132 with a threshold of +-25%).
inline constexpr float kEdgeRatioThreshold = 1.5f;

// Captures from the decoded `blocks` (reader.nodes() order). Surfels no view
// saw keep their stored weight when the set has one, else get the mean
// captured weight of their node (1 when the node was never seen).
Result<CapturedWeights> captureWeights(gpu::Context& ctx, const TilesetReader& reader, const std::vector<BlockData>& blocks,
                                       const CaptureOptions& options, CaptureStats* stats);

}  // namespace surfcast
