// The in-memory (and chunk-file) record of the builder: an input point or a
// resampled surfel. Positions are relative to the root box minimum, in double
// precision, so huge georeferenced coordinates lose nothing before quantization.
#pragma once

#include <cstdint>

#include "vec3.h"

namespace surfcast {

struct Surfel {
    Vec3d position;          // world position minus the root minimum
    Vec3f normal;            // unit; zero until estimated
    uint16_t color[3] = {};  // 16-bit channels (8-bit inputs scaled by 257)
    uint16_t source = 0;     // orientation rule of the input it came from (NormalContext::rules)
    float count = 1;         // input points it stands for: weights centroids when resampling
    // LiDAR attributes (0 where the input has none): resampled levels take the
    // prefiltered intensity and the majority class and returns (sampler.h).
    uint16_t intensity = 0;
    uint8_t classification = 0;
    uint8_t returns = 0;     // return number in bits 0-3, number of returns in bits 4-7
    uint32_t row = 0;        // its stored scalar fields' row in the ScalarTable (sampler.h) of the nodes being built
    uint8_t alpha = 255;     // opacity, 255 = opaque; resampled levels take it prefiltered, as colour
    // A leaf point of the set an update decoded (update.h): the set's leaves
    // are distinct points (the build merged the exact duplicates), even where
    // quantization gave two of them one position, so two such are never merged.
    bool fromSet = false;
    // An input point's own sampling, measured where its normal is estimated
    // and isolation is on (normals.h): the distance to its spacingK-th nearest input point (-1:
    // not measured; kScanDkToMeasure: to measure) and the RMS distance of those neighbours from its fitted
    // plane over it, in units of kScanSpreadUnit, for the isolation of input
    // points (level_attributes.h, "Isolated surfels").
    uint16_t scanSpread = 0;
    float scanDk = -1;
};
inline constexpr float kScanSpreadUnit = 1e-4f;
// scanDk of a set's input point that an update decoded, whose normal the
// build estimated: measured again (its normal kept), as a build would have.
inline constexpr float kScanDkToMeasure = -2.f;
// 64 bytes of fields: chunk files store Surfel records as they are.
static_assert(sizeof(Surfel) == 64, "chunk files store Surfel records raw; keep them compact");

}  // namespace surfcast
