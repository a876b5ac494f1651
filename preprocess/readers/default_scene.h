// The built-in default scene: a ground plane, a box, a sphere and a cylinder
// with checkerboard and stripe textures, captured by two simulated terrestrial
// scanners. Each scanner casts rays on a jittered azimuth/elevation grid, so the
// sampling is irregular and its density falls with distance; ranges carry
// Gaussian noise. Colours, no normals. Deterministic from the seed.
#pragma once

#include <memory>
#include <vector>

#include "input_point.h"

namespace surfcast {

struct SceneOptions {
    uint64_t seed = 1;
    // Total points over both scans, about; the ray grid is sized from it.
    uint64_t targetPoints = 1'500'000;
};

// One reader per scanner position; each describes its scan origin.
std::vector<std::unique_ptr<PointReader>> openDefaultScene(const SceneOptions& options);

}  // namespace surfcast
