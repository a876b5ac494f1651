#include "texture_field.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "octree_key.h"

namespace surfcast {

namespace {
constexpr uint32_t kLeafTriangles = 4;
constexpr double kReach = 3;          // sigmas of the Gaussian integrated
// A footprint's texel rectangle at the chosen mip level is at most this big
// (about 50 x 50 where texture coordinates are sane); a stretched one takes the
// texture's mean instead of looping without end.
constexpr double kMaxFootprintTexels = 1 << 16;
}  // namespace

TextureField::TextureField(const MeshTriangles& mesh, const Vec3d& origin) {
    for (const Texture& t : mesh.textures) mips_.emplace_back(t.rgb.empty() ? Texture{"", 1, 1, {128, 128, 128}} : t);
    const auto& pos = mesh.vertices.positions;
    Box3d bounds;
    for (size_t i = 0; i + 2 < mesh.triangles.size(); i += 3) {
        Tri t;
        t.a = pos[mesh.triangles[i]] - origin;
        t.b = pos[mesh.triangles[i + 1]] - origin;
        t.c = pos[mesh.triangles[i + 2]] - origin;
        const Vec3d cross = surfcast::cross(t.b - t.a, t.c - t.a);
        t.area = 0.5 * length(cross);
        if (!(t.area > 0)) continue;
        t.normal = cross * (1 / (2 * t.area));
        // Facing as the surfels do: the mesh reader's vertex normals, which
        // point out of the object whichever way the faces wind.
        const auto& vn = mesh.vertices.normals;
        const Vec3f around = vn[mesh.triangles[i]] + vn[mesh.triangles[i + 1]] + vn[mesh.triangles[i + 2]];
        if (dot(t.normal, cast<double>(around)) < 0) t.normal = t.normal * -1.0;
        t.size = std::sqrt(2 * t.area);
        const size_t f = i / 3;
        t.texture = f < mesh.triangleTexture.size() ? mesh.triangleTexture[f] : -1;
        if (f < mesh.cornerUvs.size()) t.uv = mesh.cornerUvs[f];
        if (f < mesh.triangleColor.size()) t.color = mesh.triangleColor[f];
        if (t.texture >= 0) {
            const Texture& level0 = mips_[size_t(t.texture)].levels[0];
            const double du1 = t.uv[2] - t.uv[0], dv1 = t.uv[3] - t.uv[1], du2 = t.uv[4] - t.uv[0], dv2 = t.uv[5] - t.uv[1];
            const double uvArea = 0.5 * std::fabs(du1 * dv2 - dv1 * du2);
            t.texelsPerUnit = std::sqrt(uvArea * level0.width * level0.height / t.area);
        }
        t.lo = {std::min({t.a.x, t.b.x, t.c.x}), std::min({t.a.y, t.b.y, t.c.y}), std::min({t.a.z, t.b.z, t.c.z})};
        t.hi = {std::max({t.a.x, t.b.x, t.c.x}), std::max({t.a.y, t.b.y, t.c.y}), std::max({t.a.z, t.b.z, t.c.z})};
        bounds.extend(t.lo);
        bounds.extend(t.hi);
        tris_.push_back(t);
    }
    if (tris_.empty()) return;
    // Morton order of the centroids, then halve.
    const Vec3d extent = bounds.max - bounds.min;
    const double edge = std::max({extent.x, extent.y, extent.z, 1e-300});
    std::vector<std::pair<uint64_t, uint32_t>> keys(tris_.size());
    for (uint32_t i = 0; i < tris_.size(); ++i) {
        const Vec3d c = (tris_[i].a + tris_[i].b + tris_[i].c) * (1.0 / 3) - bounds.min;
        auto q = [&](double v) { return uint32_t(std::clamp(v / edge * 2097151.0, 0.0, 2097151.0)); };
        keys[i] = {mortonCode(q(c.x), q(c.y), q(c.z)), i};
    }
    std::sort(keys.begin(), keys.end());
    std::vector<Tri> sorted;
    sorted.reserve(tris_.size());
    for (const auto& k : keys) sorted.push_back(tris_[k.second]);
    tris_.swap(sorted);
    nodes_.reserve(2 * tris_.size() / kLeafTriangles + 2);
    build(0, uint32_t(tris_.size()));
}

int32_t TextureField::build(uint32_t begin, uint32_t end) {
    const int32_t index = int32_t(nodes_.size());
    nodes_.push_back({});
    Node node;
    node.begin = begin;
    node.end = end;
    node.lo = tris_[begin].lo;
    node.hi = tris_[begin].hi;
    for (uint32_t i = begin + 1; i < end; ++i)
        for (int a = 0; a < 3; ++a) {
            node.lo[a] = std::min(node.lo[a], tris_[i].lo[a]);
            node.hi[a] = std::max(node.hi[a], tris_[i].hi[a]);
        }
    if (end - begin > kLeafTriangles) {
        const uint32_t mid = begin + (end - begin) / 2;
        node.left = build(begin, mid);
        node.right = build(mid, end);
    }
    nodes_[size_t(index)] = node;
    return index;
}

template <class F>
void TextureField::forEachNear(const Vec3d& p, double radius, F&& f) const {
    if (nodes_.empty()) return;
    auto near = [&](const Vec3d& lo, const Vec3d& hi) {
        double d2 = 0;
        for (int a = 0; a < 3; ++a) {
            const double d = p[a] < lo[a] ? lo[a] - p[a] : p[a] > hi[a] ? p[a] - hi[a] : 0;
            d2 += d * d;
        }
        return d2 <= radius * radius;
    };
    int32_t stack[64];
    int top = 0;
    stack[top++] = 0;
    while (top > 0) {
        const Node& node = nodes_[size_t(stack[--top])];
        if (!near(node.lo, node.hi)) continue;
        if (node.left < 0) {
            for (uint32_t i = node.begin; i < node.end; ++i)
                if (near(tris_[i].lo, tris_[i].hi)) f(tris_[i]);
            continue;
        }
        stack[top++] = node.left;
        stack[top++] = node.right;
    }
}

bool TextureField::filter(const Vec3d& p, const Vec3f& n, double sigma, Vec3f* out) const {
    if (!(sigma > 0)) return false;
    const double reach = kReach * sigma, reach2 = reach * reach;
    const Vec3d normal = cast<double>(n);
    Vec3d sum;
    double weight = 0;
    auto add = [&](const Vec3f& c, double w) {
        sum += cast<double>(c) * w;
        weight += w;
    };
    forEachNear(p, reach, [&](const Tri& t) {
        if (dot(t.normal, normal) < 0) return;  // the other side
        const double d = dot(p - t.a, t.normal);
        if (d * d >= reach2) return;
        Vec3f color = t.color;
        if (t.texture >= 0) {
            if (textured(t, p, sigma, add)) return;
            // Texture coordinates so stretched that the footprint holds
            // more texels than kMaxFootprintTexels even at the chosen level:
            // the texture repeats many times under it, and its mean stands in.
            const Texture& top = mips_[size_t(t.texture)].levels.back();
            color = Vec3f{top.rgb[0] / 255.f, top.rgb[1] / 255.f, top.rgb[2] / 255.f};
        }
        // A plain colour: the Gaussian's integral over the triangle, on a
        // lattice in its plane centred on p's projection.
        const double inv2s2 = 1 / (2 * sigma * sigma);
        const Vec3d origin = p - t.normal * d;
        const Vec3d e1 = normalizeOrZero(t.b - t.a), e2 = cross(t.normal, e1);
        const double step = std::min(sigma / 2, t.size / 2), r = std::sqrt(reach2 - d * d);
        double u[3], v[3];
        const Vec3d corners[3] = {t.a, t.b, t.c};
        for (int k = 0; k < 3; ++k) {
            u[k] = dot(corners[k] - origin, e1);
            v[k] = dot(corners[k] - origin, e2);
        }
        const double det = (u[1] - u[0]) * (v[2] - v[0]) - (u[2] - u[0]) * (v[1] - v[0]);
        if (det == 0) return;
        const long i0 = long(std::ceil(std::max(std::min({u[0], u[1], u[2]}), -r) / step));
        const long i1 = long(std::floor(std::min(std::max({u[0], u[1], u[2]}), r) / step));
        const long j0 = long(std::ceil(std::max(std::min({v[0], v[1], v[2]}), -r) / step));
        const long j1 = long(std::floor(std::min(std::max({v[0], v[1], v[2]}), r) / step));
        for (long i = i0; i <= i1; ++i)
            for (long j = j0; j <= j1; ++j) {
                const double x = double(i) * step, y = double(j) * step, dist2 = x * x + y * y + d * d;
                if (dist2 > reach2) continue;
                const double b1 = ((x - u[0]) * (v[2] - v[0]) - (u[2] - u[0]) * (y - v[0])) / det;
                const double b2 = ((u[1] - u[0]) * (y - v[0]) - (x - u[0]) * (v[1] - v[0])) / det;
                if (b1 < 0 || b2 < 0 || b1 + b2 > 1) continue;
                add(color, step * step * std::exp(-dist2 * inv2s2));
            }
    });
    if (!(weight > 0)) return false;
    *out = cast<float>(sum * (1 / weight));
    return true;
}

template <class Add>
bool TextureField::textured(const Tri& t, const Vec3d& p, double sigma, Add&& add) const {
    // The paper's sum over texels, w = Σ c_i ⟨r, n_i⟩ / Σ ⟨r, n_i⟩, with ⟨r, n_i⟩
    // taken as the kernel at the texel's centre on the surface times the
    // texel's area there. Texels come from the mip level whose texels are
    // at most half a sigma wide on the surface (level 0 below that); a texel
    // of that level is the average of m x m texels (variance (m² - 1)/12
    // texel² along each axis), which the Gaussian gives up to keep sigma².
    const MipTexture& mip = mips_[size_t(t.texture)];
    const double perUnit = t.texelsPerUnit;  // level-0 texels per world unit
    const size_t l = std::min(mip.levels.size() - 1, size_t(std::floor(std::log2(std::max(1.0, 0.5 * sigma * perUnit)))));
    const Texture& level = mip.levels[l];
    const double m = std::exp2(double(l));
    const double var = std::max(sigma * sigma - (m * m - 1) / 12 / (perUnit * perUnit), sigma * sigma / 2);
    const double inv2s2 = 1 / (2 * var), reach2 = kReach * kReach * sigma * sigma;
    // Texture space of this level: texel (a, b) is centred at
    // (a + 0.5, b + 0.5) in s = u W, q = (1 - v) H (rows from the top).
    const double W = level.width, H = level.height;
    const double s0 = t.uv[0] * W, q0 = (1 - t.uv[1]) * H;
    const double s1 = t.uv[2] * W - s0, q1 = (1 - t.uv[3]) * H - q0;
    const double s2 = t.uv[4] * W - s0, q2 = (1 - t.uv[5]) * H - q0;
    const double det = s1 * q2 - s2 * q1;  // twice the triangle's area in texels of this level
    if (std::fabs(det) < 4) {
        // Fewer than about two texels: the triangle as one sample at its centroid.
        const Vec3d c = (t.a + t.b + t.c) * (1.0 / 3);
        const double dist2 = dot(c - p, c - p);
        if (dist2 <= reach2)
            add(level.sample((t.uv[0] + t.uv[2] + t.uv[4]) / 3, (t.uv[1] + t.uv[3] + t.uv[5]) / 3), t.area * std::exp(-dist2 * inv2s2));
        return true;
    }
    const double texelArea = t.area / (0.5 * std::fabs(det));
    // The texels whose centres lie in the triangle and, on the surface,
    // within reach: rows of the footprint's bounding box in texture space
    // (its disc mapped by the triangle's Jacobian J, from the plane's
    // orthonormal frame to texels), each clipped to the triangle.
    const Vec3d e1 = t.b - t.a, e2 = t.c - t.a;
    const double len1 = length(e1);
    const Vec3d f1 = e1 * (1 / len1), f2 = cross(t.normal, f1);
    const double x2 = dot(e2, f1), y2 = dot(e2, f2);  // e2 in the frame; e1 is (len1, 0)
    // J [E1 E2] = [T1 T2] with E1 = (len1, 0), E2 = (x2, y2).
    const double j00 = s1 / len1, j10 = q1 / len1;
    const double j01 = (s2 - j00 * x2) / y2, j11 = (q2 - j10 * x2) / y2;
    const double d = dot(p - t.a, t.normal), rr = reach2 - d * d;
    if (!(rr > 0)) return true;
    const double r = std::sqrt(rr);
    // p's projection in texture space.
    const double px = dot(p - t.a, f1), py = dot(p - t.a, f2);
    const double ps = s0 + j00 * px + j01 * py, pq = q0 + j10 * px + j11 * py;
    const double hs = std::hypot(j00, j01) * r, hq = std::hypot(j10, j11) * r;
    const double sLo = std::max(std::min({0.0, s1, s2}) + s0, ps - hs), sHi = std::min(std::max({0.0, s1, s2}) + s0, ps + hs);
    const double qLo = std::max(std::min({0.0, q1, q2}) + q0, pq - hq), qHi = std::min(std::max({0.0, q1, q2}) + q0, pq + hq);
    if ((sHi - sLo + 1) * (qHi - qLo + 1) > kMaxFootprintTexels) return false;
    const long c0 = long(std::ceil(qLo - 0.5)), c1 = long(std::floor(qHi - 0.5));
    auto wrap = [](long i, long n) { return size_t(((i % n) + n) % n); };
    // Barycentric b1, b2 of texel (a, b): affine in a along a row.
    const double b1a = q2 / det, b2a = -q1 / det;
    for (long b = c0; b <= c1; ++b) {
        const double dq = double(b) + 0.5 - q0;
        // At a = 0: ds = 0.5 - s0.
        const double b1c = ((0.5 - s0) * q2 - s2 * dq) / det, b2c = (s1 * dq - (0.5 - s0) * q1) / det;
        double lo = std::ceil(sLo - 0.5), hi = std::floor(sHi - 0.5);
        // b1 >= 0, b2 >= 0, b1 + b2 <= 1, each linear in a.
        auto clip = [&](double slope, double at0, double bound, bool atLeast) {
            // slope a + at0 >= bound (atLeast) or <= bound.
            if (slope == 0) {
                if (atLeast ? at0 < bound : at0 > bound) hi = lo - 1;
                return;
            }
            const double a = (bound - at0) / slope;
            if ((slope > 0) == atLeast) lo = std::max(lo, std::ceil(a - 1e-9));
            else hi = std::min(hi, std::floor(a + 1e-9));
        };
        clip(b1a, b1c, 0, true);
        clip(b2a, b2c, 0, true);
        clip(b1a + b2a, b1c + b2c, 1, false);
        for (long a = long(lo); a <= long(hi); ++a) {
            const double b1 = b1a * double(a) + b1c, b2 = b2a * double(a) + b2c;
            if (b1 < -1e-9 || b2 < -1e-9 || b1 + b2 > 1 + 1e-9) continue;
            const Vec3d x = t.a + e1 * b1 + e2 * b2;
            const double dist2 = dot(x - p, x - p);
            if (dist2 > reach2) continue;
            const uint8_t* texel = &level.rgb[3 * (wrap(b, level.height) * size_t(level.width) + wrap(a, level.width))];
            add(Vec3f{texel[0] / 255.f, texel[1] / 255.f, texel[2] / 255.f}, texelArea * std::exp(-dist2 * inv2s2));
        }
    }
    return true;
}

}  // namespace surfcast
