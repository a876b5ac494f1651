#include "gaussians.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "byte_io.h"

namespace surfcast {

namespace {

constexpr uint32_t kSpzMagic = 0x5053474e;  // "NGSP"
constexpr uint32_t kSpzVersion = 2;
constexpr size_t kSpzMaxPoints = 10'000'000;  // what SPZ's reader accepts
// SPZ's byte encodings (Niantic's load-spz.cc, version 2): colours as the DC
// coefficient times 0.15 about 127.5, scales as 16 (ln s + 10).
constexpr double kSpzColorScale = 0.15;

uint8_t toByte(double v) { return uint8_t(std::clamp(std::round(v), 0.0, 255.0)); }

}  // namespace

std::array<float, 4> rotationToNormal(const Vec3f& n) {
    // Half-way between z and n: q = (z × n, 1 + z·n), normalized; n = -z
    // turns half a circle about x.
    const double w = 1.0 + n.z;
    if (w < 1e-9) return {1, 0, 0, 0};
    const double x = -n.y, y = n.x, len = std::sqrt(x * x + y * y + w * w);
    return {float(x / len), float(y / len), 0.f, float(w / len)};
}

void Gaussians::add(const Vec3f& position, const Vec3f& normal, float sigma, float thickness, float opacity, const Vec3f& color) {
    positions.push_back(position);
    scales.push_back({sigma, sigma, sigma * thickness});
    rotations.push_back(rotationToNormal(normal));
    opacities.push_back(opacity);
    colors.push_back(color);
}

Result<std::vector<uint8_t>> writeSpz(const Gaussians& g) {
    const size_t n = g.size();
    if (n > kSpzMaxPoints) return Status::error("SPZ holds at most 10 million points, not " + std::to_string(n));
    double largest = 0;
    for (const Vec3f& p : g.positions) largest = std::max({largest, std::fabs(double(p.x)), std::fabs(double(p.y)), std::fabs(double(p.z))});
    // The most fraction bits that keep every coordinate within 24 signed bits.
    int fraction = 0;
    while (fraction < 23 && std::round(largest * double(1 << (fraction + 1))) <= double((1 << 23) - 1)) ++fraction;
    if (std::round(largest * double(1 << fraction)) > double((1 << 23) - 1))
        return Status::error("a position " + std::to_string(largest) + " from its tile's centre is beyond SPZ's 24-bit range");

    std::vector<uint8_t> raw(16 + n * (9 + 1 + 3 + 3 + 3));
    le::put<uint32_t>(raw.data(), kSpzMagic);
    le::put<uint32_t>(raw.data() + 4, kSpzVersion);
    le::put<uint32_t>(raw.data() + 8, uint32_t(n));
    raw[12] = 0;  // spherical-harmonics degree
    raw[13] = uint8_t(fraction);
    raw[14] = 0;  // flags: not antialiased, no extensions
    raw[15] = 0;
    uint8_t* p = raw.data() + 16;
    for (size_t i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a) {
            const int32_t fixed = int32_t(std::lround(double(g.positions[i][a]) * double(1 << fraction)));
            *p++ = uint8_t(fixed & 0xff), *p++ = uint8_t((fixed >> 8) & 0xff), *p++ = uint8_t((fixed >> 16) & 0xff);
        }
    for (size_t i = 0; i < n; ++i) *p++ = toByte(g.opacities[i] * 255.0);
    for (size_t i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c) *p++ = toByte((g.colors[i][c] - 0.5) / kShY00 * kSpzColorScale * 255.0 + 127.5);
    for (size_t i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a) *p++ = toByte((std::log(std::max(g.scales[i][a], 1e-30f)) + 10.0) * 16.0);
    for (size_t i = 0; i < n; ++i) {
        const auto& q = g.rotations[i];
        const double sign = q[3] < 0 ? -1.0 : 1.0;
        for (int a = 0; a < 3; ++a) *p++ = toByte(sign * q[size_t(a)] * 127.5 + 127.5);
    }

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

}  // namespace surfcast
