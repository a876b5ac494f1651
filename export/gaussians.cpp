#include "gaussians.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>

#include "byte_io.h"

namespace surfcast {

namespace {

constexpr uint32_t kSpzMagic = 0x5053474e;  // "NGSP"
constexpr uint32_t kSpzVersion = 2;
// SPZ's byte encodings (version 2): colours as the DC coefficient times 0.15
// about 127.5, scales as 16 (ln s + 10), rotations' x, y, z about 127.5.
constexpr double kSpzColorScale = 0.15;
// The PLY's opacity is a logit: 1 has none, so opaque is this close to it.
constexpr double kMostOpacity = 0.999;

// NaN (which add() reports through finish()) becomes 0, not undefined behaviour.
uint8_t toByte(double v) { return v >= 0 ? uint8_t(std::min(std::round(v), 255.0)) : 0; }

}  // namespace

std::array<float, 4> rotationToNormal(const Vec3f& n) {
    // Half-way between z and n: q = (z × n, 1 + z·n), normalized; n = -z
    // turns half a circle about x.
    const double w = 1.0 + n.z;
    if (w < 1e-9) return {1, 0, 0, 0};
    const double x = -n.y, y = n.x, len = std::sqrt(x * x + y * y + w * w);
    return {float(x / len), float(y / len), 0.f, float(w / len)};
}

SpzWriter::SpzWriter(double extent) {
    while (fraction_ < 23 && std::ldexp(extent, fraction_ + 1) < double((1 << 23) - 1)) ++fraction_;
}

void SpzWriter::add(const Gaussian& g) {
    nonFinite_ |= !(std::isfinite(g.sigma) && std::isfinite(g.thickness) && std::isfinite(g.opacity) && std::isfinite(g.normal.x) &&
                    std::isfinite(g.normal.y) && std::isfinite(g.normal.z) && std::isfinite(g.color.x) && std::isfinite(g.color.y) &&
                    std::isfinite(g.color.z));
    for (int a = 0; a < 3; ++a) {
        const double fixed = std::round(std::ldexp(double(g.position[a]), fraction_));
        const bool inside = std::fabs(fixed) <= double((1 << 23) - 1);  // false for NaN too
        outside_ |= !inside;
        const int32_t v = inside ? int32_t(fixed) : 0;
        positions_.push_back(uint8_t(v & 0xff)), positions_.push_back(uint8_t((v >> 8) & 0xff));
        positions_.push_back(uint8_t((v >> 16) & 0xff));
    }
    opacities_.push_back(toByte(g.opacity * 255.0));
    for (int c = 0; c < 3; ++c) colors_.push_back(toByte((g.color[c] - 0.5) / kShY00 * kSpzColorScale * 255.0 + 127.5));
    const double sigma = std::max(double(g.sigma), 1e-30);
    for (double s : {sigma, sigma, sigma * g.thickness}) scales_.push_back(toByte((std::log(std::max(s, 1e-30)) + 10.0) * 16.0));
    const auto q = rotationToNormal(g.normal);  // w >= 0, as SPZ 2 keeps it
    for (int a = 0; a < 3; ++a) rotations_.push_back(toByte(q[size_t(a)] * 127.5 + 127.5));
}

Result<std::vector<uint8_t>> SpzWriter::finish() const {
    const size_t n = size();
    if (n > kMaxPoints) return Status::error("SPZ holds at most 10 million points, not " + std::to_string(n));
    if (outside_) return Status::error("a position lies beyond the extent SPZ's fixed point was sized for");
    if (nonFinite_) return Status::error("a Gaussian's size, normal, opacity or colour is not a finite number");
    std::vector<uint8_t> raw(16);
    le::put<uint32_t>(raw.data(), kSpzMagic);
    le::put<uint32_t>(raw.data() + 4, kSpzVersion);
    le::put<uint32_t>(raw.data() + 8, uint32_t(n));
    raw[12] = 0;  // spherical-harmonics degree
    raw[13] = uint8_t(fraction_);
    raw[14] = 0;  // flags: not antialiased, no extensions
    raw[15] = 0;
    for (const auto* column : {&positions_, &opacities_, &colors_, &scales_, &rotations_})
        raw.insert(raw.end(), column->begin(), column->end());

    // gzip (window bits 16 + 15), as SPZ readers inflate it.
    z_stream z = {};
    if (deflateInit2(&z, Z_DEFAULT_COMPRESSION, Z_DEFLATED, 16 + MAX_WBITS, 9, Z_DEFAULT_STRATEGY) != Z_OK)
        return Status::error("zlib: cannot start compressing");
    std::vector<uint8_t> out(deflateBound(&z, uLong(raw.size())));
    z.next_in = raw.data();
    z.avail_in = uInt(raw.size());
    z.next_out = out.data();
    z.avail_out = uInt(out.size());
    const int result = deflate(&z, Z_FINISH);
    out.resize(z.total_out);
    deflateEnd(&z);
    if (result != Z_STREAM_END) return Status::error("zlib: compressing failed");
    return out;
}

std::string plyHeader(uint64_t count, const std::string& comment) {
    std::string h = "ply\nformat binary_little_endian 1.0\ncomment " + comment + "\nelement vertex " + std::to_string(count) + "\n";
    for (const char* name : {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                             "rot_0", "rot_1", "rot_2", "rot_3"})
        h += std::string("property float ") + name + "\n";
    return h + "end_header\n";
}

void plyRecord(const Gaussian& g, uint8_t out[kPlyRecordBytes]) {
    const double alpha = std::clamp(double(g.opacity), 1 - kMostOpacity, kMostOpacity);
    const double sigma = std::max(double(g.sigma), 1e-30);
    const auto q = rotationToNormal(g.normal);
    const float values[17] = {g.position.x, g.position.y, g.position.z, 0, 0, 0,
                              float((g.color.x - 0.5) / kShY00), float((g.color.y - 0.5) / kShY00), float((g.color.z - 0.5) / kShY00),
                              float(std::log(alpha / (1 - alpha))),
                              float(std::log(sigma)), float(std::log(sigma)), float(std::log(std::max(sigma * g.thickness, 1e-30))),
                              q[3], q[0], q[1], q[2]};
    for (int i = 0; i < 17; ++i) le::put<float>(out + 4 * i, values[i]);
}

}  // namespace surfcast
