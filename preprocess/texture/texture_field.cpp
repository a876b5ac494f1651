#include "texture_field.h"

// The solves run in parallel over groups, one per thread. Eigen's own OpenMP
// (its sparse products) would start a team inside each, and with a single
// thread per chunk worker (an inactive region) it does: 2 chunk workers then
// ran 4 spinning threads on 2 cores, a multi-chunk build 25x slower. So the
// library is compiled with EIGEN_DONT_PARALLELIZE (preprocess/CMakeLists.txt:
// a define here would come too late in a unity batch that included Eigen).
#include <Eigen/IterativeLinearSolvers>
#include <Eigen/Sparse>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <unordered_map>

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
    for (const auto& t : mesh.textures) mips_.emplace_back(t);
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
            const Texture& level0 = mips_[size_t(t.texture)].level(0);
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

uint64_t TextureField::bytes() const {
    uint64_t sum = tris_.capacity() * sizeof(Tri) + nodes_.capacity() * sizeof(Node);
    for (const MipTexture& m : mips_) sum += m.level(0).bytes() + m.coarserBytes();
    return sum;
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

template <class Test, class F>
void TextureField::forEachWhere(Test&& test, F&& f) const {
    if (nodes_.empty()) return;
    int32_t stack[64];
    int top = 0;
    stack[top++] = 0;
    while (top > 0) {
        const Node& node = nodes_[size_t(stack[--top])];
        if (!test(node.lo, node.hi)) continue;
        if (node.left < 0) {
            for (uint32_t i = node.begin; i < node.end; ++i)
                if (test(tris_[i].lo, tris_[i].hi)) f(tris_[i]);
            continue;
        }
        stack[top++] = node.left;
        stack[top++] = node.right;
    }
}

template <class F>
void TextureField::forEachInBox(const Vec3d& lo, const Vec3d& hi, F&& f) const {
    forEachWhere([&](const Vec3d& a, const Vec3d& b) {
        return a.x <= hi.x && b.x >= lo.x && a.y <= hi.y && b.y >= lo.y && a.z <= hi.z && b.z >= lo.z;
    }, f);
}

template <class F>
void TextureField::forEachNear(const Vec3d& p, double radius, F&& f) const {
    forEachWhere([&](const Vec3d& lo, const Vec3d& hi) {
        double d2 = 0;
        for (int a = 0; a < 3; ++a) {
            const double d = p[a] < lo[a] ? lo[a] - p[a] : p[a] > hi[a] ? p[a] - hi[a] : 0;
            d2 += d * d;
        }
        return d2 <= radius * radius;
    }, f);
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
            const MipTexture& mip = mips_[size_t(t.texture)];
            const Texture& top = mip.level(mip.levels() - 1);
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
    const size_t l = std::min(mip.levels() - 1, size_t(std::floor(std::log2(std::max(1.0, 0.5 * sigma * perUnit)))));
    const Texture& level = mip.level(l);
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

template <class F>
void TextureField::forEachSample(const Vec3d& lo, const Vec3d& hi, double step, F&& f) const {
    auto inBox = [&](const Vec3d& x) {
        return x.x >= lo.x && x.x <= hi.x && x.y >= lo.y && x.y <= hi.y && x.z >= lo.z && x.z <= hi.z;
    };
    forEachInBox(lo, hi, [&](const Tri& t) {
        auto value = [&](double b1, double b2, double spacing) {
            if (t.texture < 0) return t.color;
            const double u = t.uv[0] + b1 * (t.uv[2] - t.uv[0]) + b2 * (t.uv[4] - t.uv[0]);
            const double v = t.uv[1] + b1 * (t.uv[3] - t.uv[1]) + b2 * (t.uv[5] - t.uv[1]);
            return mips_[size_t(t.texture)].sample(u, v, t.texelsPerUnit * spacing);
        };
        if (t.area < 2 * step * step) {
            const Vec3d c = (t.a + t.b + t.c) * (1.0 / 3);
            if (inBox(c)) f(c, t.normal, t.area, value(1.0 / 3, 1.0 / 3, std::sqrt(t.area)));
            return;
        }
        // The lattice in the triangle's frame: origin a, axes f1 along ab and
        // f2 = normal x f1; c sits at (x2, y2).
        const Vec3d e1 = t.b - t.a, e2 = t.c - t.a;
        const double len1 = length(e1);
        const Vec3d f1 = e1 * (1 / len1), f2 = cross(t.normal, f1);
        const double x2 = dot(e2, f1), y2 = dot(e2, f2);
        // The box's extent in the frame, clipped to the triangle's.
        double x0 = std::min(0.0, x2), x1 = std::max(len1, x2), v0 = std::min(0.0, y2), v1 = std::max(0.0, y2);
        double bx0 = HUGE_VAL, bx1 = -HUGE_VAL, by0 = HUGE_VAL, by1 = -HUGE_VAL;
        for (int corner = 0; corner < 8; ++corner) {
            const Vec3d q{corner & 1 ? hi.x : lo.x, corner & 2 ? hi.y : lo.y, corner & 4 ? hi.z : lo.z};
            const double x = dot(q - t.a, f1), y = dot(q - t.a, f2);
            bx0 = std::min(bx0, x), bx1 = std::max(bx1, x), by0 = std::min(by0, y), by1 = std::max(by1, y);
        }
        x0 = std::max(x0, bx0), x1 = std::min(x1, bx1), v0 = std::max(v0, by0), v1 = std::min(v1, by1);
        if (x0 > x1 || v0 > v1) return;
        for (long j = long(std::ceil(v0 / step)); j <= long(std::floor(v1 / step)); ++j) {
            const double y = double(j) * step, b2 = y / y2;
            if (b2 < 0 || b2 > 1) continue;
            for (long i = long(std::ceil(x0 / step)); i <= long(std::floor(x1 / step)); ++i) {
                const double x = double(i) * step, b1 = (x - b2 * x2) / len1;
                if (b1 < 0 || b1 + b2 > 1) continue;
                const Vec3d p = t.a + f1 * x + f2 * y;
                if (inBox(p)) f(p, t.normal, step * step, value(b1, b2, step));
            }
        }
    });
}

namespace {

// R w = rhs with every w_k in [0, 1], the range of a stored colour. Clamping
// the unconstrained solution afterwards undoes it: where surfels crowd, the
// least squares trade large coefficients of opposite signs (measured on a
// uniformly random sampling of a checkerboard: coefficients from -3 to 4, and
// clamped they reconstruct worse than the point samples). So an active set
// that only grows: the unknowns a solution puts out of range are fixed at the
// bound they passed, their columns moved to the right-hand side, and the rest
// solved again, at most kBoundRounds times (then clamped).
constexpr int kBoundRounds = 8;

Eigen::VectorXd solveBounded(const Eigen::SparseMatrix<double>& r, const Eigen::VectorXd& rhs, const Eigen::VectorXd& guess,
                             const FitParams& params, FitReport* report) {
    const Eigen::Index n = r.rows();
    Eigen::VectorXd w = guess.cwiseMax(0.0).cwiseMin(1.0);
    std::vector<uint8_t> fixed(size_t(n), 0);
    Eigen::ConjugateGradient<Eigen::SparseMatrix<double>, Eigen::Lower | Eigen::Upper> cg;
    cg.setMaxIterations(params.maxIterations);
    cg.setTolerance(params.tolerance);
    Eigen::SparseMatrix<double> reduced;
    Eigen::VectorXd b;
    int iterations = 0;
    for (int round = 0; round < kBoundRounds; ++round) {
        bool anyFixed = false;
        for (uint8_t x : fixed) anyFixed |= x != 0;
        if (!anyFixed) {
            cg.compute(r);
            b = rhs;
        } else {
            // Fixed unknowns: identity rows and columns, their values on the right.
            Eigen::VectorXd atBounds = Eigen::VectorXd::Zero(n);
            for (Eigen::Index k = 0; k < n; ++k)
                if (fixed[size_t(k)]) atBounds[k] = w[k];
            b = rhs - r * atBounds;
            reduced = r;
            for (Eigen::Index col = 0; col < reduced.outerSize(); ++col)
                for (Eigen::SparseMatrix<double>::InnerIterator it(reduced, col); it; ++it)
                    if (fixed[size_t(it.row())] || fixed[size_t(col)]) it.valueRef() = it.row() == col ? 1.0 : 0.0;
            for (Eigen::Index k = 0; k < n; ++k)
                if (fixed[size_t(k)]) b[k] = w[k];
            cg.compute(reduced);
        }
        w = cg.solveWithGuess(b, w);
        iterations += int(cg.iterations());
        report->maxResidual = std::max(report->maxResidual, cg.error());
        bool added = false;
        for (Eigen::Index k = 0; k < n; ++k)
            if (!fixed[size_t(k)] && (w[k] < 0 || w[k] > 1)) {
                w[k] = w[k] < 0 ? 0 : 1;
                fixed[size_t(k)] = 1;
                added = true;
            }
        if (!added) break;
    }
    report->iterations = std::max<uint64_t>(report->iterations, uint64_t(iterations));
    report->maxIterations = std::max(report->maxIterations, iterations);
    return w.cwiseMax(0.0).cwiseMin(1.0);
}

}  // namespace

void FitReport::add(const FitReport& o) {
    groups += o.groups;
    unknowns += o.unknowns;
    samples += o.samples;
    iterations += o.iterations;
    maxIterations = std::max(maxIterations, o.maxIterations);
    maxResidual = std::max(maxResidual, o.maxResidual);
}

FitReport TextureField::fitOptimal(std::span<FitSurfel> surfels, std::span<const std::pair<uint32_t, uint32_t>> groups,
                                   const FitParams& params) const {
    FitReport total;
    const double tangent2 = 2 * params.cutoff;  // y'y inside the kernel
    double maxSigma = 0;
    Box3d bounds;
    for (const FitSurfel& s : surfels) {
        if (s.sigma > 0 && std::isfinite(s.sigma)) maxSigma = std::max(maxSigma, s.sigma);
        bounds.extend(s.position);
    }
    if (tris_.empty() || groups.empty() || !(maxSigma > 0)) return total;

    // A uniform grid over the surfels with cells as wide as the largest
    // kernel's reach in 3D: the kernels covering a point lie in the 27 cells
    // around it.
    const double cell = maxSigma * std::sqrt(tangent2 + params.zt * params.zt);
    auto cellOf = [&](const Vec3d& p, int axis) { return int64_t(std::floor((p[axis] - bounds.min[axis]) / cell)); };
    auto key = [](int64_t x, int64_t y, int64_t z) { return uint64_t(x) << 42 | uint64_t(y) << 21 | uint64_t(z); };
    constexpr int64_t kAxisMax = (int64_t(1) << 21) - 1;
    std::vector<std::pair<uint64_t, uint32_t>> grid(surfels.size());
    for (uint32_t i = 0; i < surfels.size(); ++i) {
        const Vec3d& p = surfels[i].position;
        grid[i] = {key(std::clamp<int64_t>(cellOf(p, 0), 0, kAxisMax), std::clamp<int64_t>(cellOf(p, 1), 0, kAxisMax),
                       std::clamp<int64_t>(cellOf(p, 2), 0, kAxisMax)),
                   i};
    }
    std::sort(grid.begin(), grid.end());
    // Each occupied (x, y) column's run of the sorted grid: a surface crosses
    // a column in few cells, so a lookup scans its run instead of searching.
    std::unordered_map<uint64_t, std::pair<uint32_t, uint32_t>> columns;
    for (uint32_t i = 0; i < grid.size();) {
        uint32_t j = i + 1;
        while (j < grid.size() && grid[j].first >> 21 == grid[i].first >> 21) ++j;
        columns[grid[i].first >> 21] = {i, j};
        i = j;
    }

    std::vector<Vec3f> start(surfels.size());  // the starting guesses, read by every group
    for (size_t i = 0; i < surfels.size(); ++i) start[i] = surfels[i].color;
    std::vector<FitReport> reports(groups.size());

#pragma omp parallel num_threads(params.threads)
    {
        std::vector<int32_t> column(surfels.size(), -1);  // surfel -> unknown of the current group
        std::vector<uint32_t> unknowns;
        std::vector<Eigen::Triplet<double>> entries;
        std::vector<Vec3f> values;
        std::vector<std::pair<uint32_t, double>> covering;
#pragma omp for schedule(dynamic, 1)
        for (size_t g = 0; g < groups.size(); ++g) {
            const auto [begin, end] = groups[g];
            if (begin >= end) continue;
            Box3d box;
            double minSigma = HUGE_VAL, groupMax = 0;
            for (uint32_t i = begin; i < end; ++i) {
                box.extend(surfels[i].position);
                if (surfels[i].sigma > 0) minSigma = std::min(minSigma, surfels[i].sigma), groupMax = std::max(groupMax, surfels[i].sigma);
            }
            if (!(groupMax > 0)) continue;
            const Vec3d grow{2 * cell, 2 * cell, 2 * cell};
            // Lattice step from the group's smallest kernel, but never below
            // a quarter of its largest (per-surfel radii can be tiny).
            const double step = params.sampleStep * std::max(minSigma, groupMax / 4);
            unknowns.clear();
            entries.clear();
            values.clear();
            int32_t row = 0;
            forEachSample(box.min - grow, box.max + grow, step, [&](const Vec3d& p, const Vec3d& n, double area, const Vec3f& value) {
                covering.clear();
                double sum = 0;
                const int64_t cx = cellOf(p, 0), cy = cellOf(p, 1), cz = cellOf(p, 2);
                for (int64_t x = cx - 1; x <= cx + 1; ++x)
                    for (int64_t y = cy - 1; y <= cy + 1; ++y) {
                        if (x < 0 || y < 0 || x > kAxisMax || y > kAxisMax) continue;
                        auto column = columns.find(key(x, y, 0) >> 21);
                        if (column == columns.end()) continue;
                        for (uint32_t e = column->second.first; e < column->second.second; ++e) {
                            const int64_t z = int64_t(grid[e].first & uint64_t(kAxisMax));
                            if (z < cz - 1 || z > cz + 1) continue;
                            const FitSurfel& s = surfels[grid[e].second];
                            if (!(s.sigma > 0)) continue;
                            const Vec3d d = p - s.position;
                            const Vec3d sn = cast<double>(s.normal);
                            const double along = dot(d, sn);
                            if (std::fabs(along) > params.zt * s.sigma || dot(sn, n) < 0) continue;
                            const double y2 = (dot(d, d) - along * along) / (s.sigma * s.sigma);
                            if (y2 > tangent2) continue;
                            const double w = std::exp(-0.5 * y2);
                            covering.push_back({grid[e].second, w});
                            sum += w;
                        }
                    }
                if (!(sum > 0)) return;  // no kernel here: a hole the renderer leaves too
                const double scale = std::sqrt(area) / sum;
                for (const auto& [k, w] : covering) {
                    if (column[k] < 0) {
                        column[k] = int32_t(unknowns.size());
                        unknowns.push_back(k);
                    }
                    entries.emplace_back(row, column[k], w * scale);
                }
                values.push_back(value * float(std::sqrt(area)));
                ++row;
            });
            FitReport& report = reports[g];
            report.groups = 1;
            report.unknowns = unknowns.size();
            report.samples = size_t(row);
            if (!unknowns.empty()) {
                const Eigen::Index n = Eigen::Index(unknowns.size());
                Eigen::SparseMatrix<double> a(row, n);
                a.setFromTriplets(entries.begin(), entries.end());
                Eigen::SparseMatrix<double> r = Eigen::SparseMatrix<double>(a.transpose()) * a;
                double meanDiagonal = 0;
                for (Eigen::Index k = 0; k < n; ++k) meanDiagonal += r.coeff(k, k);
                const double ridge = params.ridge * meanDiagonal / double(n);
                for (Eigen::Index k = 0; k < n; ++k) r.coeffRef(k, k) += ridge;
                Eigen::VectorXd f(row), guess(n);
                for (int channel = 0; channel < 3; ++channel) {
                    for (int32_t q = 0; q < row; ++q) f[q] = values[size_t(q)][channel];
                    for (Eigen::Index k = 0; k < n; ++k) guess[k] = start[unknowns[size_t(k)]][channel];
                    const Eigen::VectorXd rhs = a.transpose() * f + ridge * guess;
                    const Eigen::VectorXd w = solveBounded(r, rhs, guess, params, &report);
                    for (Eigen::Index k = 0; k < n; ++k) {
                        const uint32_t i = unknowns[size_t(k)];
                        if (i >= begin && i < end) surfels[i].color[channel] = float(w[k]);
                    }
                }
            }
            for (uint32_t k : unknowns) column[k] = -1;
        }
    }
    for (const FitReport& r : reports) total.add(r);
    return total;
}

}  // namespace surfcast
