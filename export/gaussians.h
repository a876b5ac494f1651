// Surfels as 3D Gaussians, for the splat formats (docs/EXPORT.md,
// "Gaussians"): each surfel a flat Gaussian in its tangent plane, and SPZ,
// Niantic's compressed container for them, which CesiumJS reads inside glTF
// (KHR_gaussian_splatting_compression_spz_2) and splat viewers read alone.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "status.h"
#include "vec3.h"

namespace surfcast {

// A surfel of radius r (its own, or its node's h) as a Gaussian of standard
// deviation sigmaScale · k · r in its tangent plane (k: the set's kernel
// scale, Surfcast's kernel V^r = (k r)² I) and `thickness` · that along its
// normal, with the surfel's opacity times `opacity`.
struct GaussianOptions {
    double sigmaScale = 1.0;
    double thickness = 0.01;
    double opacity = 1.0;
};

// Gaussians in the caller's frame (positions relative to some origin).
struct Gaussians {
    std::vector<Vec3f> positions;
    std::vector<Vec3f> scales;            // standard deviations along the local axes (linear, not log)
    std::vector<std::array<float, 4>> rotations;  // unit quaternions x, y, z, w (w >= 0): local to the frame
    std::vector<float> opacities;         // in [0, 1]
    std::vector<Vec3f> colors;            // display sRGB in [0, 1]
    size_t size() const { return positions.size(); }
    void add(const Vec3f& position, const Vec3f& normal, float sigma, float thickness, float opacity, const Vec3f& color);
};

// The rotation taking the local z axis to `normal` (unit), w >= 0.
std::array<float, 4> rotationToNormal(const Vec3f& normal);

// The zeroth spherical-harmonics coefficient that reproduces a display
// colour c in [0, 1]: (c - 0.5) / Y00 (KHR_gaussian_splatting).
inline constexpr double kShY00 = 0.28209479177387814;

// SPZ version 2 (gzip over a 16-byte header, then 24-bit fixed-point
// positions, opacities, colours, log scales and rotations, each as bytes;
// no higher spherical harmonics), stored as given: no change of axes.
// The fixed point's fraction takes as many bits as the largest coordinate
// leaves. Fails beyond SPZ's 10 million points.
Result<std::vector<uint8_t>> writeSpz(const Gaussians& g);

}  // namespace surfcast
