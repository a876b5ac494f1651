// The GPU renderer (client/render/splat_renderer) against the CPU reference
// and against hand-derived expectations, on synthetic surfels, with the
// Khronos validation layer on: every test also asserts zero validation errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "coloring.h"
#include "cpu_reference.h"
#include "gpu_fixture.h"
#include "splat_renderer.h"
#include "surfel_set.h"
#include "test_support.h"

namespace surfcast {
namespace {

constexpr int kW = 256, kH = 192;

// A square patch of the plane z = 0 (n x n jittered samples, spacing d) in
// a frame given by its centre and two axes; colour from `paint(u, v)`.
template <typename Paint>
void addPlane(SurfelSet& set, Vec3d centre, Vec3d axisU, Vec3d axisV, int n, double d, double jitter, Paint paint,
              uint32_t seed = 1) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> jit(-jitter * d, jitter * d);
    Vec3f normal = cast<float>(normalizeOrZero(cross(axisU, axisV)));
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            double u = (i - 0.5 * (n - 1)) * d + jit(rng), v = (j - 0.5 * (n - 1)) * d + jit(rng);
            // r: about the 8th-neighbour distance of a jittered grid, as the
            // preprocessor's h would be.
            addSurfel(set, centre + axisU * u + axisV * v, normal, float(1.5 * d), paint(u, v));
        }
}

Camera lookAt(Vec3d eye, Vec3d target, Vec3d up = {0, 0, 1}, double fov = 40) { return {eye, target, up, fov}; }

struct Diff {
    double mean = 0;      // mean |a - b| over pixels covered in either, in [0, 1]
    size_t coveredA = 0, coveredB = 0, coveredBoth = 0;
};

Diff compare(const Image& a, const Image& b) {
    Diff d;
    size_t n = 0;
    for (size_t i = 0; i < a.rgba.size(); i += 4) {
        bool ca = a.rgba[i + 3] == 255, cb = b.rgba[i + 3] == 255;
        d.coveredA += ca;
        d.coveredB += cb;
        d.coveredBoth += ca && cb;
        if (!ca && !cb) continue;
        for (int c = 0; c < 3; ++c) d.mean += std::abs(int(a.rgba[i + c]) - int(b.rgba[i + c])) / 255.0;
        n += 3;
    }
    d.mean /= std::max<size_t>(n, 1);
    return d;
}

// Largest deviation of any covered pixel from `color` (in [0, 1]).
double maxDeviation(const Image& img, Vec3f color, size_t* covered) {
    double worst = 0;
    *covered = 0;
    for (size_t i = 0; i < img.rgba.size(); i += 4) {
        if (img.rgba[i + 3] != 255) continue;
        ++*covered;
        for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(img.rgba[i + c] / 255.0 - color[c]));
    }
    return worst;
}

// With SURFCAST_TEST_OUT set, images under comparison are written there.
void dump(const Image& img, const std::string& name) {
    if (const char* dir = std::getenv("SURFCAST_TEST_OUT")) (void)writePng(img, std::string(dir) + "/" + name + ".png");
}

class RenderTest : public test::GpuTest {
protected:
    Image gpuRender(const SurfelSet& set, const Camera& camera, RenderSettings settings,
                    RendererOptions options = {}, GpuFrameStats* stats = nullptr) {
        return GpuTest::gpuRender(set, camera, kW, kH, settings, options, stats);
    }
    Image cpuRender(const SurfelSet& set, const Camera& camera, const RenderSettings& settings) {
        auto view = makeViewTransform(camera, set.origin, kW, kH);
        EXPECT_TRUE(view);
        return renderCpuReference(set, *view, settings);
    }
};

// A checkerboard of 8x8-sample squares on a 160 x 160 plane.
SurfelSet checkerboard(Vec3d origin) {
    SurfelSet set;
    set.origin = origin;
    addPlane(set, origin, {1, 0, 0}, {0, 1, 0}, 160, 1.0, 0.3, [](double u, double v) {
        bool odd = (int(std::floor(u / 8)) + int(std::floor(v / 8))) & 1;
        return odd ? Vec3f{0.9f, 0.9f, 0.9f} : Vec3f{0.1f, 0.2f, 0.6f};
    });
    sortMorton(set);
    return set;
}

// The plane seen at 60 degrees from its normal.
Camera sixtyDegrees(Vec3d centre) {
    double a = 60 * M_PI / 180;
    return lookAt(centre + Vec3d{0, -std::sin(a), std::cos(a)} * 140.0, centre);
}

TEST_F(RenderTest, PerPixelEwaMatchesCpuReferenceOnCheckerboardAt60Degrees) {
    SurfelSet set = checkerboard({0, 0, 0});
    RenderSettings settings;
    Image gpu = gpuRender(set, sixtyDegrees({0, 0, 0}), settings);
    Image cpu = cpuRender(set, sixtyDegrees({0, 0, 0}), settings);
    dump(gpu, "checker_gpu");
    dump(cpu, "checker_cpu");
    Diff d = compare(gpu, cpu);
    // Threshold (derivation in docs/RENDERER.md, "Testing against the CPU
    // reference"): the two evaluate the same kernel; they differ by the local
    // affine approximation of the CPU path (relative weight error up to
    // sqrt(2c) * r/z * tan(theta) ~ 2% at the splat edge here), which only
    // shows where colours change (the checker edges, ~15% of pixels, contrast
    // 0.8), plus 8-bit rounding (1/510): about 0.2 * 0.8 * 0.02 + 0.002 = 0.005.
    EXPECT_LT(d.mean, 0.01) << "mean abs error";
    EXPECT_GT(d.coveredBoth, size_t(0.25 * kW * kH));
    // Coverage agrees except for single pixels along the outline.
    EXPECT_LT(std::max(d.coveredA, d.coveredB) - d.coveredBoth, size_t(0.01 * kW * kH));
}

TEST_F(RenderTest, QuadAndGeometryExpansionAgree) {
    if (!context_->geometryShader) GTEST_SKIP() << "device has no geometry shaders";
    SurfelSet set = checkerboard({0, 0, 0});
    Image quad = gpuRender(set, sixtyDegrees({0, 0, 0}), {}, {Expansion::Quad});
    Image geom = gpuRender(set, sixtyDegrees({0, 0, 0}), {}, {Expansion::Geometry});
    Diff d = compare(quad, geom);
    EXPECT_LT(d.mean, 1.0 / 255);
    EXPECT_EQ(d.coveredA, d.coveredB);
}

TEST_F(RenderTest, ConstantColourPlaneWithJitterStaysConstantWithPerPixelNormalization) {
    const Vec3f colour{0.7f, 0.4f, 0.2f};
    SurfelSet set;
    set.origin = {0, 0, 0};
    addPlane(set, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 120, 1.0, 0.45, [&](double, double) { return colour; });
    RenderSettings settings;  // unlit, per-pixel normalization
    size_t covered = 0;
    for (Camera cam : {sixtyDegrees({0, 0, 0}), lookAt({0, 0, 60}, {0, 0, 0}, {0, 1, 0}), lookAt({0, -20, 300}, {0, 0, 0})}) {
        Image img = gpuRender(set, cam, settings);
        EXPECT_LE(maxDeviation(img, colour, &covered), 0.01) << "camera eye " << cam.eye.x << "," << cam.eye.y << "," << cam.eye.z;
        EXPECT_GT(covered, size_t(0.2 * kW * kH));
    }
    // Seen from straight above the plane fills the view: no holes anywhere.
    Image top = gpuRender(set, lookAt({0, 0, 60}, {0, 0, 0}, {0, 1, 0}), settings);
    maxDeviation(top, colour, &covered);
    EXPECT_EQ(covered, size_t(kW * kH));
}

TEST_F(RenderTest, FrontPlaneHidesBackPlaneFartherThanZt) {
    // z_t = 0.5 r = 0.75; planes 2 apart (> z_t). The back plane is larger, so
    // it must show around the front one.
    SurfelSet set;
    set.origin = {0, 0, 0};
    const Vec3f red{0.9f, 0.1f, 0.1f}, blue{0.1f, 0.1f, 0.9f};
    addPlane(set, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 60, 1.0, 0.3, [&](double, double) { return red; }, 1);
    addPlane(set, {0, 0, -2}, {1, 0, 0}, {0, 1, 0}, 140, 1.0, 0.3, [&](double, double) { return blue; }, 2);
    Camera cam = lookAt({0, 0, 150}, {0, 0, 0}, {0, 1, 0});
    for (RenderMode mode : {RenderMode::EwaPixel, RenderMode::EwaNoPrefilter, RenderMode::CpuReference}) {
        RenderSettings settings;
        settings.mode = mode;
        Image img = mode == RenderMode::CpuReference ? cpuRender(set, cam, settings) : gpuRender(set, cam, settings);
        ASSERT_EQ(img.rgba.size(), size_t(kW * kH * 4));
        // Centre pixel: the front plane only; a pixel near the border: the back plane.
        const uint8_t* centre = &img.rgba[4 * (kH / 2 * kW + kW / 2)];
        const uint8_t* edge = &img.rgba[4 * (kH / 2 * kW + 8)];
        EXPECT_NEAR(centre[0] / 255.0, red.x, 0.01) << renderModeName(mode);
        EXPECT_NEAR(centre[2] / 255.0, red.z, 0.01) << renderModeName(mode);
        EXPECT_NEAR(edge[2] / 255.0, blue.z, 0.01) << renderModeName(mode);
        // Over the whole front square (projected: 60 units at distance 150),
        // no blue leaks through.
        double halfPx = 0.5 * 60 / 150 * kH / (2 * std::tan(20 * M_PI / 180)) - 3;
        for (int y = int(kH / 2 - halfPx); y < int(kH / 2 + halfPx); ++y)
            for (int x = int(kW / 2 - halfPx); x < int(kW / 2 + halfPx); ++x)
                ASSERT_NEAR(img.rgba[4 * (y * kW + x) + 2] / 255.0, red.z, 0.01)
                    << renderModeName(mode) << " pixel " << x << "," << y;
    }
}

// A clip box draws exactly what the set cut to the box (in double, world
// coordinates) draws, in every mode, translucent too, and in the CPU
// reference; at the origin and georeferenced. The box takes the front plane
// away, so the back plane shows where it was hidden, and cuts the back plane
// in half. (Under the sanitizers, georeferenced only: the same code.)
TEST_F(RenderTest, ClipBoxDrawsWhatTheSetCutToTheBoxDraws) {
    const Vec3f red{0.9f, 0.1f, 0.1f}, blue{0.1f, 0.1f, 0.9f};
    std::vector<Vec3d> origins = {Vec3d{1e6 + 0.37, -2e6 + 0.11, 3e5}};
    if (!test::kSanitized) origins.push_back({0, 0, 0});
    for (const Vec3d& origin : origins) {
        SurfelSet set;
        set.origin = origin;
        addPlane(set, origin, {1, 0, 0}, {0, 1, 0}, 60, 1.0, 0.3, [&](double, double) { return red; }, 1);
        addPlane(set, origin + Vec3d{0, 0, -2}, {1, 0, 0}, {0, 1, 0}, 140, 1.0, 0.3, [&](double, double) { return blue; }, 2);
        const Box3d box{origin + Vec3d{-80, -80, -3}, origin + Vec3d{10.25, 80, -1}};
        SurfelSet cut = set;
        cut.surfels.clear();
        for (const auto& g : set.surfels) {
            const Vec3d p = origin + Vec3d{g.px, g.py, g.pz};
            // Far from the faces: float rounding cannot decide (the 1 mm margin
            // is thousands of float steps at 10 m from the origin).
            ASSERT_GT(std::fabs(p.x - box.max.x), 1e-3);
            if (p.x >= box.min.x && p.x <= box.max.x && p.y >= box.min.y && p.y <= box.max.y && p.z >= box.min.z &&
                p.z <= box.max.z)
                cut.surfels.push_back(g);
        }
        ASSERT_GT(cut.surfels.size(), 8000u);
        ASSERT_LT(cut.surfels.size(), set.surfels.size() * 6 / 10);
        const Camera cam = lookAt(origin + Vec3d{0, 0, 150}, origin, {0, 1, 0});
        for (RenderMode mode : {RenderMode::Points, RenderMode::Circles, RenderMode::EwaNoPrefilter, RenderMode::EwaSurfel,
                                RenderMode::EwaPixel, RenderMode::CpuReference}) {
            // Points and circles stay opaque: translucency is the ewa modes' alone.
            const bool opaqueMode = mode == RenderMode::Points || mode == RenderMode::Circles;
            for (float opacity : {1.f, 0.5f}) {
                if (opaqueMode && opacity < 1) continue;
                RenderSettings settings;
                settings.mode = mode;
                settings.opacity = opacity;
                auto render = [&](const SurfelSet& s, const RenderSettings& r) {
                    return mode == RenderMode::CpuReference ? cpuRender(s, cam, r) : gpuRender(s, cam, r);
                };
                const Image whole = render(cut, settings);
                settings.clip = box;
                const Image clipped = render(set, settings);
                const std::string what = std::string(renderModeName(mode)) + " opacity " + std::to_string(opacity) +
                                         (origin.x != 0 ? " georeferenced" : "");
                dump(clipped, "clip_" + std::to_string(int(mode)) + "_" + std::to_string(int(opacity * 10)));
                Diff d = compare(clipped, whole);
                EXPECT_EQ(d.mean, 0) << what;
                EXPECT_EQ(d.coveredA, d.coveredB) << what;
                EXPECT_EQ(d.coveredA, d.coveredBoth) << what;
                if (mode != RenderMode::Points) {  // points leave gaps
                    // The centre: the back plane, which the front one hid; the
                    // right edge (x > 10.25 there): the background.
                    const uint8_t* centre = &clipped.rgba[4 * (kH / 2 * kW + kW / 2)];
                    const uint8_t* right = &clipped.rgba[4 * (kH / 2 * kW + kW - 8)];
                    EXPECT_GT(int(centre[2]), int(centre[0]) + 60) << what;
                    EXPECT_LT(right[3], 255) << what;
                }
            }
        }
    }
}

TEST_F(RenderTest, GuardsAgainstGrazingNearPlaneEmptyAndNonFiniteInput) {
    const Vec3f colour{0.3f, 0.6f, 0.9f};
    SurfelSet plane;
    plane.origin = {0, 0, 0};
    addPlane(plane, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 100, 1.0, 0.3, [&](double, double) { return colour; });
    size_t covered = 0;
    for (RenderMode mode : {RenderMode::EwaPixel, RenderMode::EwaSurfel, RenderMode::EwaNoPrefilter, RenderMode::Circles,
                            RenderMode::Points}) {
        RenderSettings settings;
        settings.mode = mode;
        // 89.9 degrees between the view and the plane's normal.
        double a = 89.9 * M_PI / 180;
        Image grazing = gpuRender(plane, lookAt(Vec3d{0, -std::sin(a), std::cos(a)} * 120.0, {0, 0, 0}), settings);
        if (mode != RenderMode::EwaSurfel) {  // per-surfel colours are not normalized
            EXPECT_LE(maxDeviation(grazing, colour, &covered), 0.01) << renderModeName(mode);
        }
        // Camera 0.2 above the plane (r = 1.5): splats straddle the near plane
        // and the camera sits inside their extent.
        Image close = gpuRender(plane, lookAt({0, 0, 0.2}, {0, 30, 0}, {0, 0, 1}, 90), settings);
        if (mode != RenderMode::EwaSurfel) {
            EXPECT_LE(maxDeviation(close, colour, &covered), 0.01) << renderModeName(mode);
        }
        EXPECT_GT(covered, 0u) << renderModeName(mode);
    }

    // Camera inside a cloud of randomly oriented surfels: renders, and every
    // covered pixel is the cloud's one colour.
    SurfelSet cloud;
    cloud.origin = {0, 0, 0};
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(-1, 1);
    for (int i = 0; i < 20000; ++i)
        addSurfel(cloud, {u(rng) * 50.0, u(rng) * 50.0, u(rng) * 50.0}, normalizeOrZero(Vec3f{u(rng), u(rng), u(rng)}),
                  2.f, colour);
    Image inside = gpuRender(cloud, lookAt({0, 0, 0}, {0, 1, 0}, {0, 0, 1}, 90), {});
    EXPECT_LE(maxDeviation(inside, colour, &covered), 0.01);
    EXPECT_GT(covered, size_t(0.5 * kW * kH));

    // Non-finite positions (red) must leave no trace; degenerate radii (green:
    // h = 0, inf, NaN) draw as dots (r falls back to one pixel's worth: with
    // the cutoff and the low-pass at most ~5 px across, 25 px in area).
    const float nan = std::nanf(""), inf = INFINITY;
    const uint32_t up = packNormalOct({0, 0, 1}), red = packColor({1, 0, 0}), green = packColor({0, 1, 0});
    auto count = [](const Image& img, bool wantRed) {
        size_t n = 0;
        for (size_t i = 0; i < img.rgba.size(); i += 4) {
            const uint8_t* p = &img.rgba[i];
            bool isRed = p[0] > 128 && p[1] < 100 && p[2] < 100, isGreen = p[1] > 128 && p[0] < 100 && p[2] < 100;
            n += p[3] == 255 && (wantRed ? isRed : isGreen);
        }
        return n;
    };
    SurfelSet bad = plane;
    bad.surfels.push_back({nan, 0, 0.5f, 1, up, red, 1, 0});
    bad.surfels.push_back({0, inf, 0.5f, 1, up, red, 1, 0});
    bad.surfels.push_back({-inf, nan, inf, 1, up, red, 1, 0});
    bad.surfels.push_back({10, 10, 0.5f, 0, up, green, 1, 0});
    bad.surfels.push_back({-10, 10, 0.5f, inf, up, green, 1, 0});
    bad.surfels.push_back({0, -10, 0.5f, nan, up, green, 1, 0});
    for (RenderMode mode : {RenderMode::EwaPixel, RenderMode::EwaSurfel, RenderMode::EwaNoPrefilter, RenderMode::Points,
                            RenderMode::Circles, RenderMode::CpuReference}) {
        RenderSettings settings;
        settings.mode = mode;
        Camera cam = sixtyDegrees({0, 0, 0});
        Image img = mode == RenderMode::CpuReference ? cpuRender(bad, cam, settings) : gpuRender(bad, cam, settings);
        EXPECT_EQ(count(img, true), 0u) << renderModeName(mode);
        // ewa-surfel is unnormalized (the dots blend with the background);
        // circles are flat at their centre's depth, so the plane's nearer
        // circles may cover a dot.
        if (mode == RenderMode::EwaSurfel || mode == RenderMode::Circles) continue;
        EXPECT_GE(count(img, false), 3u) << renderModeName(mode);
        EXPECT_LE(count(img, false), 3 * 25u) << renderModeName(mode);
    }
    // Non-finite weights: ewa-surfel (the one mode that reads them) drops the surfel.
    SurfelSet badWeights = plane;
    badWeights.surfels.push_back({5, 0, 0.5f, 1, up, red, nan, 0});
    badWeights.surfels.push_back({-5, 0, 0.5f, 1, up, red, inf, 0});
    RenderSettings surfel;
    surfel.mode = RenderMode::EwaSurfel;
    EXPECT_EQ(count(gpuRender(badWeights, sixtyDegrees({0, 0, 0}), surfel), true), 0u);

    // An empty set: the background only.
    SurfelSet empty;
    GpuFrameStats stats;
    Image none = gpuRender(empty, lookAt({0, -10, 0}, {0, 0, 0}), {}, {}, &stats);
    EXPECT_EQ(stats.pixelsCovered, 0u);
    ASSERT_EQ(none.rgba.size(), size_t(kW * kH * 4));
    EXPECT_EQ(none.rgba[0], 255);
    Image cpuNone = cpuRender(empty, lookAt({0, -10, 0}, {0, 0, 0}), {});
    EXPECT_EQ(cpuNone.rgba[3], 0);
}

TEST_F(RenderTest, HugeCoordinatesRenderLikeTheOrigin) {
    // DESIGN.md decision 4: georeferenced data at 10^6 renders without jitter.
    Vec3d far{1e6 + 0.37, -2e6 + 0.11, 3e5};
    Image near = gpuRender(checkerboard({0, 0, 0}), sixtyDegrees({0, 0, 0}), {});
    Image shifted = gpuRender(checkerboard(far), sixtyDegrees(far), {});
    Diff d = compare(near, shifted);
    EXPECT_LT(d.mean, 1.0 / 255);
    EXPECT_LT(std::max(d.coveredA, d.coveredB) - d.coveredBoth, 10u);
}

TEST_F(RenderTest, EveryModeDrawsAndReportsTimes) {
    SurfelSet set = checkerboard({0, 0, 0});
    for (RenderMode mode : {RenderMode::Points, RenderMode::Circles, RenderMode::EwaNoPrefilter, RenderMode::EwaSurfel,
                            RenderMode::EwaPixel}) {
        RenderSettings settings;
        settings.mode = mode;
        GpuFrameStats stats;
        gpuRender(set, sixtyDegrees({0, 0, 0}), settings, {}, &stats);
        EXPECT_EQ(stats.splats, set.surfels.size());
        EXPECT_GT(stats.pixelsCovered, size_t(0.2 * kW * kH)) << renderModeName(mode);
        if (context_->timestamps) {
            EXPECT_GT(stats.totalMs, 0) << renderModeName(mode);
        }
    }
}

TEST(SurfelSet, OctahedralNormalsAndMortonOrder) {
    std::mt19937 rng(3);
    std::normal_distribution<float> g;
    for (int i = 0; i < 1000; ++i) {
        Vec3f n = normalizeOrZero(Vec3f{g(rng), g(rng), g(rng)});
        Vec3f back = unpackNormalOct(packNormalOct(n));
        EXPECT_GT(dot(n, back), 0.99999f);
    }
    EXPECT_GT(dot(unpackNormalOct(packNormalOct({0, 0, -1})), Vec3f{0, 0, -1}), 0.99999f);
    // The 8 corners of a cube come out in Z order: z fastest, then y, then x.
    SurfelSet set;
    for (int i = 7; i >= 0; --i) addSurfel(set, {double(i >> 2), double(i >> 1 & 1), double(i & 1)}, {0, 0, 1}, 1, {});
    sortMorton(set);
    for (int i = 0; i < 8; ++i) {
        EXPECT_EQ(set.surfels[i].px, float(i >> 2));
        EXPECT_EQ(set.surfels[i].py, float(i >> 1 & 1));
        EXPECT_EQ(set.surfels[i].pz, float(i & 1));
    }
}

TEST(Camera, ParsesChecksAndFrames) {
    auto c = parseCamera("1,2,3,4,5,6,0,0,1,50");
    ASSERT_TRUE(c);
    EXPECT_EQ(c->eye, (Vec3d{1, 2, 3}));
    EXPECT_EQ(c->fovYDegrees, 50);
    EXPECT_FALSE(parseCamera("1,2,3"));
    EXPECT_FALSE(parseCamera("0,0,0,0,0,0,0,0,1,45"));  // eye == target
    EXPECT_FALSE(parseCamera("0,0,0,1,0,0,1,0,0,45"));  // up along the view
    EXPECT_FALSE(parseCamera("0,0,0,1,0,0,0,0,1,180"));
    EXPECT_FALSE(parseCamera("0,0,0,1,0,0,0,0,1,45,"));
    auto path = parseCameraPath(R"({"frames":[{"eye":[0,-5,0],"target":[0,0,0]},{"eye":[1,-5,0],"target":[0,0,0],"fov":30}]})", "p");
    ASSERT_TRUE(path) << path.status().message();
    EXPECT_EQ(path->size(), 2u);
    EXPECT_EQ((*path)[1].fovYDegrees, 30);
    EXPECT_FALSE(parseCameraPath(R"({"frames":[{"eye":[0,-5],"target":[0,0,0]}]})", "p"));
    EXPECT_FALSE(parseCameraPath("[", "p"));

    // frameBox: every corner of the box projects inside the image, within
    // 90 % of its half extents, and two reach that margin on opposite sides
    // in x or y: the box fills the view, centred (from every direction, for
    // a portrait image and a flat box too).
    for (const auto& [extent, aspect] : {std::pair{Vec3d{30, 10, 15}, 16.0 / 9}, std::pair{Vec3d{24, 24, 2}, 16.0 / 9},
                                          std::pair{Vec3d{24, 24, 2}, 9.0 / 16}}) {
        Box3d box;
        box.extend(Vec3d{1e6, 2e6, 10});
        box.extend(Vec3d{1e6, 2e6, 10} + extent);
        Vec3d origin = (box.min + box.max) * 0.5;
        const int w = aspect > 1 ? 1600 : 900, h = aspect > 1 ? 900 : 1600;
        for (int direction = 0; direction < 8; ++direction) {
            auto view = makeViewTransform(frameBox(box, aspect, 45, direction), origin, w, h);
            ASSERT_TRUE(view);
            double lo[2] = {HUGE_VAL, HUGE_VAL}, hi[2] = {-HUGE_VAL, -HUGE_VAL};
            for (int i = 0; i < 8; ++i) {
                Vec3d p{i & 1 ? box.max.x : box.min.x, i & 2 ? box.max.y : box.min.y, i & 4 ? box.max.z : box.min.z};
                Vec3f o = view->apply(cast<float>(p - origin));
                ASSERT_GT(o.z, 0);
                double x = view->eta * o.x / o.z / (w / 2), y = view->eta * o.y / o.z / (h / 2);
                EXPECT_LE(std::fabs(x), 0.9 + 1e-4) << direction;
                EXPECT_LE(std::fabs(y), 0.9 + 1e-4) << direction;
                lo[0] = std::min(lo[0], x), hi[0] = std::max(hi[0], x), lo[1] = std::min(lo[1], y), hi[1] = std::max(hi[1], y);
            }
            const bool spansX = std::fabs(hi[0] - 0.9) < 1e-4 && std::fabs(lo[0] + 0.9) < 1e-4;
            const bool spansY = std::fabs(hi[1] - 0.9) < 1e-4 && std::fabs(lo[1] + 0.9) < 1e-4;
            EXPECT_TRUE(spansX || spansY) << "direction " << direction << ": x " << lo[0] << ".." << hi[0] << ", y " << lo[1]
                                          << ".." << hi[1];
        }
    }
    // A box of one point, far from the origin: an eye apart from the target.
    Box3d point;
    point.extend(Vec3d{4e7, -3e7, 100});
    EXPECT_TRUE(makeViewTransform(frameBox(point, 1.0), point.min, 64, 64));
}

// Backface culling's default and the framing that goes with it. Normals are
// oriented where every input's normal_source is: read from the input, or
// turned towards a scanner. The default view turns to the side a scan's
// surfaces face when they all face one way (a sensor-frame scan seen from
// behind), and stays where a closed object faces every way alike.
TEST(BackfaceCulling, DefaultFollowsNormalSourceAndFramingFacesTheSurfaces) {
    EXPECT_TRUE(normalsOriented("input"));
    EXPECT_TRUE(normalsOriented("estimated-scan-origin"));
    EXPECT_TRUE(normalsOriented("input+estimated-scan-origin"));
    EXPECT_FALSE(normalsOriented("estimated-up"));
    EXPECT_FALSE(normalsOriented("estimated-outward"));
    EXPECT_FALSE(normalsOriented("input+estimated-up"));
    EXPECT_FALSE(normalsOriented(""));
    EXPECT_TRUE(settingsForSet(0.5, true, true).backfaceCull);
    EXPECT_FALSE(settingsForSet(0.5, true, false).backfaceCull);

    // A wall facing -z (a scan in its sensor's frame, sensor at the origin):
    // the usual view, from +z above, sees its back.
    SurfelSet wall;
    for (int i = 0; i < 100; ++i) addSurfel(wall, {double(i % 10), double(i / 10), 5}, {0, 0, -1}, 1.f, {1, 1, 1});
    const int d = frontDirection(wall);
    EXPECT_LT(frameDirections()[size_t(d)].z, 0) << "the chosen view looks from the side the wall faces";
    const Camera c = frameBox(wall.bounds, 1.0, 45, d);
    EXPECT_LT((c.eye - c.target).z, 0);
    // A sphere faces every way: the usual view.
    SurfelSet sphere;
    for (int i = 0; i < 2000; ++i) {
        const double z = 1 - 2 * (i + 0.5) / 2000, phi = i * 2.399963;
        const Vec3d n{std::sqrt(1 - z * z) * std::cos(phi), std::sqrt(1 - z * z) * std::sin(phi), z};
        addSurfel(sphere, n * 10.0, cast<float>(n), 0.5f, {1, 1, 1});
    }
    EXPECT_EQ(frontDirection(sphere), 0);
    EXPECT_EQ(frameBox(sphere.bounds, 1.0).eye, frameBox(sphere.bounds, 1.0, 45, 0).eye);
}

}  // namespace
}  // namespace surfcast

namespace surfcast {

TEST(Coloring, ViridisIsMatplotlibsViridis) {
    // matplotlib 3.11.2's colormaps["viridis"] at t = k/20 (printed by
    // matplotlib itself; the palette is its 256-entry table). The table in
    // coloring.cpp holds the deciles to 3 decimals: at even k the two agree
    // within that rounding (0.0005, plus float error). Between deciles it
    // interpolates linearly; the chord misses the curve by at most 0.052
    // (blue at 0.95: (0.150 + 0.144) / 2 against 0.0953). The palette once
    // lacked its 0.9 sample and spread 10 samples over 11 places: 0.21 off
    // at 0.9, 0.013 at 0.1.
    const float reference[21][3] = {
        {0.2670f, 0.0049f, 0.3294f}, {0.2803f, 0.0734f, 0.3972f}, {0.2826f, 0.1409f, 0.4575f}, {0.2730f, 0.2045f, 0.5017f},
        {0.2539f, 0.2653f, 0.5300f}, {0.2297f, 0.3224f, 0.5457f}, {0.2068f, 0.3718f, 0.5531f}, {0.1839f, 0.4224f, 0.5569f},
        {0.1636f, 0.4711f, 0.5581f}, {0.1448f, 0.5191f, 0.5566f}, {0.1276f, 0.5669f, 0.5506f}, {0.1194f, 0.6111f, 0.5390f},
        {0.1347f, 0.6586f, 0.5176f}, {0.1858f, 0.7049f, 0.4853f}, {0.2669f, 0.7488f, 0.4406f}, {0.3692f, 0.7889f, 0.3829f},
        {0.4775f, 0.8214f, 0.3182f}, {0.6060f, 0.8507f, 0.2367f}, {0.7414f, 0.8734f, 0.1496f}, {0.8762f, 0.8911f, 0.0953f},
        {0.9932f, 0.9062f, 0.1439f}};
    for (int k = 0; k <= 20; ++k) {
        const Vec3f c = viridis(float(k) / 20.f);
        const float tolerance = k % 2 == 0 ? 0.0006f : 0.053f;
        for (int i = 0; i < 3; ++i) EXPECT_NEAR(c[i], reference[k][i], tolerance) << "t = " << k / 20.0 << ", channel " << i;
    }
    // Outside [0, 1] and NaN: the ends.
    EXPECT_EQ(viridis(-1.f), viridis(0.f));
    EXPECT_EQ(viridis(2.f), viridis(1.f));
    EXPECT_EQ(viridis(std::nanf("")), viridis(0.f));
}

}  // namespace surfcast
