// Surfels as 3D Gaussians, for the splat formats (docs/EXPORT.md,
// "Gaussians"): each surfel a flat Gaussian in its tangent plane, written as
// SPZ (Niantic's compressed splats, which CesiumJS reads inside glTF as
// KHR_gaussian_splatting_compression_spz_2 and splat viewers read alone) or
// as the 3D Gaussian splatting PLY.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "status.h"
#include "vec3.h"

namespace surfcast {

// A surfel of radius r (its own, or its node's h) as a Gaussian of standard
// deviation sigmaScale · k · r in its tangent plane (k: the set's kernel
// scale, Surfcast's kernel V^r = (k r)² I) and `thickness` · that along its
// normal, with the surfel's opacity times `opacity`. sigmaScale 0.75 brings
// CesiumJS's and Spark's images closest to surfcast-view's
// (bench/BENCHMARKS.md, "Splats against surfcast-view").
struct GaussianOptions {
    double sigmaScale = 0.75;
    double thickness = 0.01;
    double opacity = 1.0;
};

// One Gaussian, in the file's frame.
struct Gaussian {
    Vec3f position;
    Vec3f normal;   // unit: the local z axis
    float sigma;    // in the tangent plane
    float thickness;  // along the normal, as a fraction of sigma
    float opacity;  // [0, 1]
    Vec3f color;    // display sRGB, [0, 1]
};

// The rotation taking the local z axis to `normal` (unit), as x, y, z, w with w >= 0.
std::array<float, 4> rotationToNormal(const Vec3f& normal);

// The zeroth spherical-harmonics basis value: a display colour c comes from
// the coefficient (c - 0.5) / Y00 (KHR_gaussian_splatting).
inline constexpr double kShY00 = 0.28209479177387814;

// SPZ version 2 (Niantic's load-spz.cc): gzip over a 16-byte header, then
// 24-bit fixed-point positions, opacities, colours, log scales and
// rotations, one column after another, as bytes; no higher spherical
// harmonics. Coordinates are stored as given (SPZ's own axes are right, up,
// back). Columns grow as Gaussians arrive, 19 bytes each; finish() copies
// them once and compresses (about 64 bytes a Gaussian at the peak, measured).
// Log scales outside [-10, 5.9] (standard deviations outside 4.5e-5 to 365
// set units) clamp to that range, as SPZ's own writer clamps them.
class SpzWriter {
public:
    static constexpr size_t kMaxPoints = 10'000'000;  // what SPZ's reader accepts
    // `extent`: the largest |coordinate| to come; the fixed point's fraction
    // takes as many bits as it leaves of 24.
    explicit SpzWriter(double extent);
    void add(const Gaussian& g);
    size_t size() const { return opacities_.size(); }
    // Fails beyond kMaxPoints, for a coordinate past the extent, or for a
    // value that is not finite.
    Result<std::vector<uint8_t>> finish() const;

private:
    int fraction_ = 0;
    bool outside_ = false, nonFinite_ = false;
    std::vector<uint8_t> positions_, opacities_, colors_, scales_, rotations_;
};

// The 3D Gaussian splatting PLY (binary, little-endian, as the reference
// implementation writes it): per Gaussian x, y, z, nx, ny, nz, f_dc_0..2,
// opacity (logit), scale_0..2 (log), rot_0..3 (w, x, y, z), all float.
inline constexpr size_t kPlyRecordBytes = 17 * 4;
std::string plyHeader(uint64_t count, const std::string& comment);
void plyRecord(const Gaussian& g, uint8_t out[kPlyRecordBytes]);

}  // namespace surfcast
