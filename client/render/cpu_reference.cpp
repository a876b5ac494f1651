// Screen-space EWA splatting, Zwicker et al. 2001 (§3 the resampling kernel,
// §4 the rendering algorithm, eq. 9 per-pixel normalization).
//
// For a surfel with centre o (camera space), tangent basis s, t and
// reconstruction kernel V^r = r^2 I, the projective map of its tangent plane is
// approximated at o by the Jacobian J (DESIGN.md, "Object-space EWA in one
// screen", y row negated for the y-down screen). The screen-space resampling
// kernel is
//     rho(x) = |J| r^2 / |V|^(1/2) * exp(-1/2 d' V^-1 d),  V = J V^r J' + V^h,
// d = x - m, m the projected centre: the Gaussian G_V scaled by 2 pi |V^r|^(1/2)
// so that it peaks at 1 under magnification. That scale is the same for every
// surfel of equal r and cancels in the normalization; it makes rho the very
// function the GPU path evaluates in object space (|J M J'|^(1/2) = |J| r0 r1).
#include "cpu_reference.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace surfcast {

namespace {

struct ScreenSplat {
    float mx, my;         // projected centre, pixels
    float qa, qb, qc;     // conic V^-1 = [qa qb; qb qc]
    float amplitude;
    int x0, x1, y0, y1;   // pixel bounding box, inclusive
    Vec3f o, n;           // camera-space centre and unit normal
    float zt;             // depth offset, world units
    float depthExtent;    // the disc's half-extent in depth, world units
    Vec3f color;
    float alpha;          // opacity, the set's times settings.opacity
};

// One surface's fragment in a translucent frame's A-buffer (Zwicker 2001 §6):
// the sums of every splat that joined it, the depth of its nearest
// contribution and that one's z threshold.
struct Fragment {
    float z, zt;
    float r, g, b, w, a, nx, ny, nz, coverage;
};

// Adds contribution `c` (its sums, depth z and threshold zt) to a pixel's
// fragments, at most `layers` of them kept in depth order: it joins the first
// fragment it lies within z_t of (either one's z_t, measured from the nearer),
// else it is a fragment of its own; past `layers`, the two fragments closest
// in depth merge (§6).
void addToABuffer(Fragment* frags, uint8_t& count, int layers, const Fragment& c) {
    auto join = [](Fragment& f, const Fragment& g) {
        if (g.z < f.z) f.z = g.z, f.zt = g.zt;
        f.r += g.r, f.g += g.g, f.b += g.b, f.w += g.w, f.a += g.a;
        f.nx += g.nx, f.ny += g.ny, f.nz += g.nz, f.coverage += g.coverage;
    };
    int at = 0;
    while (at < count && frags[at].z < c.z) ++at;
    if (at > 0 && c.z - frags[at - 1].z <= frags[at - 1].zt) return join(frags[at - 1], c);
    if (at < count && frags[at].z - c.z <= c.zt) return join(frags[at], c);
    for (int i = count; i > at; --i) frags[i] = frags[i - 1];
    frags[at] = c;
    if (++count <= layers) return;
    int closest = 0;
    for (int i = 1; i + 1 < count; ++i)
        if (frags[i + 1].z - frags[i].z < frags[closest + 1].z - frags[closest].z) closest = i;
    join(frags[closest], frags[closest + 1]);
    for (int i = closest + 1; i + 1 < count; ++i) frags[i] = frags[i + 1];
    --count;
}

bool finite(const Vec3f& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// Distance along the pixel's ray to the splat's tangent plane, clamped to the
// depth range of the splat's object-space footprint: near grazing angles the
// ray meets the plane far outside the splat.
float rayDistance(const ScreenSplat& s, const Vec3f& ray, float rayLength) {
    float denom = dot(ray, s.n);
    float t = std::fabs(denom) > 1e-6f ? dot(s.o, s.n) / denom : s.o.z;
    if (!std::isfinite(t)) t = s.o.z;
    return std::clamp(t, s.o.z - s.depthExtent, s.o.z + s.depthExtent) * rayLength;
}

}  // namespace

double diagonalOf(const SurfelSet& set) { return set.bounds.empty() ? 0.0 : length(set.bounds.max - set.bounds.min); }

float nearPlaneFor(double diagonal, const ViewTransform& view) {
    // The eye's distance to the origin (the set's centre): |translation|.
    double eye = std::sqrt(double(view.rows[0][3]) * view.rows[0][3] + double(view.rows[1][3]) * view.rows[1][3] +
                           double(view.rows[2][3]) * view.rows[2][3]);
    double scale = std::max(diagonal, eye);
    return float((scale > 0 ? scale : 1.0) * kNearFraction);
}

Image renderCpuReference(const SurfelSet& set, const ViewTransform& view, const RenderSettings& settings,
                         CpuFrameStats* stats) {
    auto start = std::chrono::steady_clock::now();
    const int W = view.width, H = view.height;
    const float eta = view.eta, near = nearPlaneFor(diagonalOf(set), view);
    const float cutoff2 = 2.f * settings.cutoff, lowpass = settings.lowpassVariance;

    // Setup: one screen-space kernel per surfel.
    std::vector<ScreenSplat> splats;
    splats.reserve(set.surfels.size());
    const std::optional<LocalClip> clip = localClip(settings, set.origin);
    for (const auto& g : set.surfels) {
        if (clip && !clip->contains({g.px, g.py, g.pz})) continue;
        Vec3f o = view.apply({g.px, g.py, g.pz});
        if (!finite(o) || !(o.z >= near)) continue;  // behind the near plane (or NaN)
        Vec3f n = normalizeOrZero(view.rotate(unpackNormalOct(g.normal)));
        if (!(length(n) > 0)) continue;
        if (settings.backfaceCull && dot(n, o) > 0) continue;
        if (dot(n, o) > 0) n = n * -1.f;  // two-sided: the normal faces the eye
        Vec3f s = tangentOf(n), t = cross(n, s);
        float r = g.radius * settings.kernelScale;
        if (!(r > 0) || !std::isfinite(r)) r = o.z / eta;  // h = 0: one pixel's worth
        float k = eta / (o.z * o.z);
        float j00 = k * (s.x * o.z - s.z * o.x), j01 = k * (t.x * o.z - t.z * o.x);
        float j10 = -k * (s.y * o.z - s.z * o.y), j11 = -k * (t.y * o.z - t.z * o.y);
        float r2 = r * r;
        float va = r2 * (j00 * j00 + j01 * j01) + lowpass;
        float vb = r2 * (j00 * j10 + j01 * j11);
        float vc = r2 * (j10 * j10 + j11 * j11) + lowpass;
        float det = va * vc - vb * vb;
        float detJ = std::fabs(j00 * j11 - j01 * j10);
        if (!(det > 0) || !std::isfinite(det)) continue;  // no low-pass and J singular
        ScreenSplat sp;
        const PixelPoint m = view.project(o);
        sp.mx = m.x;
        sp.my = m.y;
        sp.qa = vc / det;
        sp.qb = -vb / det;
        sp.qc = va / det;
        sp.amplitude = detJ * r2 / std::sqrt(det);
        float ex = std::sqrt(cutoff2 * va), ey = std::sqrt(cutoff2 * vc);
        // Pixel centres at i + 0.5 inside [m - e, m + e].
        auto lo = [](float v) { return int(std::ceil(std::clamp(v - 0.5f, -1e9f, 1e9f))); };
        auto hi = [](float v) { return int(std::floor(std::clamp(v - 0.5f, -1e9f, 1e9f))); };
        sp.x0 = std::max(lo(sp.mx - ex), 0);
        sp.x1 = std::min(hi(sp.mx + ex), W - 1);
        sp.y0 = std::max(lo(sp.my - ey), 0);
        sp.y1 = std::min(hi(sp.my + ey), H - 1);
        if (sp.x0 > sp.x1 || sp.y0 > sp.y1 || !std::isfinite(sp.amplitude)) continue;
        sp.o = o;
        sp.n = n;
        // The footprint's object-space extent is that of the GPU's
        // parallelogram: the largest axis of M = r^2 I + V^h (J'J)^-1, with
        // the same clamp at grazing angles (client/shaders/splat_common.glsl).
        float ta = j00 * j00 + j10 * j10, tb = j00 * j01 + j10 * j11, tc = j01 * j01 + j11 * j11;
        float lambdaMin = 0.5f * (ta + tc) - std::sqrt(0.25f * (ta - tc) * (ta - tc) + tb * tb);
        float lambdaFloor = eta / (kMaxFilterPixels * o.z);
        float extent = std::sqrt(r2 + lowpass / std::max(lambdaMin, lambdaFloor * lambdaFloor));
        // z_t scales with the footprint's longer axis, as on the GPU
        // (splat_common.glsl, pushBack).
        sp.zt = settings.zt * extent;
        sp.depthExtent = std::sqrt(cutoff2) * extent * std::sqrt(std::max(0.f, 1.f - n.z * n.z));
        sp.color = unpackColor(g.color);
        sp.alpha = float(g.color >> 24) / 255.f * std::clamp(settings.opacity, 0.f, 1.f);
        splats.push_back(sp);
    }

    // Rasterization in row bands, one per thread: every band visits the splats
    // in the same order, so the sums do not depend on the thread count.
    std::vector<float> front(size_t(W) * H, INFINITY);
    struct Accum { float r, g, b, w, nx, ny, nz, coverage; };
    std::vector<Accum> acc(size_t(W) * H, Accum{0, 0, 0, 0, 0, 0, 0, 0});
    auto ray = [&](int x, int y) { return view.pixelRay(x + 0.5f, y + 0.5f); };
    auto forEachFragment = [&](int y0, int y1, auto&& fragment) {
        for (const ScreenSplat& sp : splats) {
            int ya = std::max(sp.y0, y0), yb = std::min(sp.y1, y1 - 1);
            for (int y = ya; y <= yb; ++y) {
                float dy = y + 0.5f - sp.my;
                for (int x = sp.x0; x <= sp.x1; ++x) {
                    float dx = x + 0.5f - sp.mx;
                    float q = sp.qa * dx * dx + 2 * sp.qb * dx * dy + sp.qc * dy * dy;
                    if (q > cutoff2) continue;
                    fragment(sp, x, y, q);
                }
            }
        }
    };
    const int threads = std::max(1, omp_get_max_threads());
    const int band = (H + threads - 1) / threads;
    auto finish = [&](Image image, size_t covered) {
        if (stats) {
            stats->splats = splats.size();
            stats->pixelsCovered = covered;
            stats->milliseconds = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        }
        return image;
    };
    // Edge antialiasing's border: a 4-neighbour of (x, y) where `covered` is false.
    auto onBorder = [&](int x, int y, auto&& covered) {
        for (auto [dx, dy] : {std::pair{1, 0}, std::pair{-1, 0}, std::pair{0, 1}, std::pair{0, -1}})
            if (!covered(size_t(std::clamp(y + dy, 0, H - 1)) * W + size_t(std::clamp(x + dx, 0, W - 1)))) return true;
        return false;
    };
    auto store = [](uint8_t* px, const Vec3f& c, float alpha) {
        px[0] = uint8_t(std::lround(std::clamp(c.x, 0.f, 1.f) * 255.f));
        px[1] = uint8_t(std::lround(std::clamp(c.y, 0.f, 1.f) * 255.f));
        px[2] = uint8_t(std::lround(std::clamp(c.z, 0.f, 1.f) * 255.f));
        px[3] = uint8_t(std::lround(std::clamp(alpha, 0.f, 1.f) * 255.f));
    };

    if (translucentFrame(settings)) {
        // Translucent (§6): every fragment goes to the A-buffer, in the
        // splats' order; then each pixel's layers blend back to front (eq. 12).
        const int layers = std::clamp(settings.layers, 1, kMaxLayers);
        const size_t slots = size_t(layers) + 1;  // one more: the arrival that forces a merge
        std::vector<Fragment> frags(size_t(W) * H * slots);
        std::vector<uint8_t> counts(size_t(W) * H, 0);
#pragma omp parallel for num_threads(threads) schedule(static, 1)
        for (int b = 0; b < threads; ++b)
            forEachFragment(b * band, std::min(H, (b + 1) * band), [&](const ScreenSplat& sp, int x, int y, float q) {
                Vec3f d = ray(x, y);
                const size_t i = size_t(y) * W + x;
                const float g = std::exp(-0.5f * q), w = sp.amplitude * g;
                const Fragment c{rayDistance(sp, d, length(d)), sp.zt, sp.color.x * w, sp.color.y * w, sp.color.z * w, w,
                                 sp.alpha * w, sp.n.x * w, sp.n.y * w, sp.n.z * w, g};
                addToABuffer(&frags[i * slots], counts[i], layers, c);
            });
        Image image{W, H, std::vector<uint8_t>(size_t(W) * H * 4)};
        size_t covered = 0;
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x) {
                const size_t i = size_t(y) * W + x;
                Vec3f c = settings.background;
                float total = 0;
                for (int k = int(counts[i]) - 1; k >= 0; --k) {
                    const Fragment& f = frags[i * slots + size_t(k)];
                    if (!(f.coverage > 0 && f.w > 0)) continue;
                    float alpha = f.a / f.w;
                    // Edge antialiasing per layer, on that layer's border: a
                    // 4-neighbour without a k-th surface (the GPU's rule).
                    if (settings.edgeAA && f.coverage < settings.edgeTau &&
                        onBorder(x, y, [&](size_t q) { return counts[q] > k; }))
                        alpha *= f.coverage / settings.edgeTau;
                    const Vec3f color = shadePixel(settings.shading, Vec3f{f.r, f.g, f.b} * (1.f / f.w), {f.nx, f.ny, f.nz}, ray(x, y));
                    c = color * alpha + c * (1.f - alpha);
                    total = alpha + total * (1.f - alpha);
                }
                covered += counts[i] > 0;
                store(&image.rgba[4 * i], c, total);
            }
        return finish(std::move(image), covered);
    }
#pragma omp parallel for num_threads(threads) schedule(static, 1)
    for (int b = 0; b < threads; ++b) {
        int y0 = b * band, y1 = std::min(H, y0 + band);
        // Pass 1, visibility: the nearest surface, pushed back by z_t.
        forEachFragment(y0, y1, [&](const ScreenSplat& sp, int x, int y, float) {
            Vec3f d = ray(x, y);
            float z = rayDistance(sp, d, length(d)) + sp.zt;
            float& f = front[size_t(y) * W + x];
            f = std::min(f, z);
        });
        // Pass 2, accumulation of the fragments in front of it.
        forEachFragment(y0, y1, [&](const ScreenSplat& sp, int x, int y, float q) {
            Vec3f d = ray(x, y);
            size_t i = size_t(y) * W + x;
            if (rayDistance(sp, d, length(d)) > front[i]) return;
            float g = std::exp(-0.5f * q);
            float w = sp.amplitude * g;
            Accum& a = acc[i];
            a.r += sp.color.x * w;
            a.g += sp.color.y * w;
            a.b += sp.color.z * w;
            a.w += w;
            a.nx += sp.n.x * w;
            a.ny += sp.n.y * w;
            a.nz += sp.n.z * w;
            a.coverage += g;
        });
    }

    // Resolve: per-pixel normalization and deferred shading.
    Image image{W, H, std::vector<uint8_t>(size_t(W) * H * 4)};
    size_t covered = 0;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            size_t i = size_t(y) * W + x;
            const Accum& a = acc[i];
            Vec3f c = settings.background;
            bool hit = a.coverage > 0 && a.w > 0;
            float alpha = 0;
            if (hit) {
                // Partial coverage on the covered region's border only, as
                // the GPU's resolve does.
                alpha = 1.f;
                if (settings.edgeAA && a.coverage < settings.edgeTau &&
                    onBorder(x, y, [&](size_t q) { return acc[q].coverage > 0; }))
                    alpha = a.coverage / settings.edgeTau;
                c = shadePixel(settings.shading, Vec3f{a.r, a.g, a.b} * (1.f / a.w), {a.nx, a.ny, a.nz}, ray(x, y));
                c = settings.background + (c - settings.background) * alpha;
                ++covered;
            }
            store(&image.rgba[4 * i], c, alpha);
        }
    return finish(std::move(image), covered);
}

}  // namespace surfcast
