// Per-surfel opacity (read, built, stored only where a point is translucent)
// and transparency (Zwicker 2001 §6: l fragment layers per pixel, blended back
// to front by eq. 12) on the GPU, with the validation layer on, and in the CPU
// reference. Expected colours are derived by hand from eq. 12 next to each
// check.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <random>

#include "block_codec.h"
#include "cpu_reference.h"
#include "gpu_fixture.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace surfcast {
namespace {

using test::TempDir;

constexpr int kW = 192, kH = 160;

// A square of surfels in the plane z = `z` (normal +z) on a jittered grid of
// spacing 1 over [-40, 40]², r = 1.5.
void addPlane(SurfelSet& set, double z, Vec3f colour, float opacity, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> jit(-0.3, 0.3);
    for (double x = -39.5; x < 40; x += 1)
        for (double y = -39.5; y < 40; y += 1)
            addSurfel(set, {x + jit(rng), y + jit(rng), z}, {0, 0, 1}, 1.5f, colour, 1.f, 0, opacity);
}

// Mean colour of the central 32 × 32 pixels, every one covered (by layers
// whose composite opacity may be under 1).
Vec3f centreColour(const Image& img) {
    Vec3f sum{0, 0, 0};
    int n = 0;
    for (int y = kH / 2 - 16; y < kH / 2 + 16; ++y)
        for (int x = kW / 2 - 16; x < kW / 2 + 16; ++x, ++n) {
            const uint8_t* p = &img.rgba[4 * size_t(y * kW + x)];
            EXPECT_GT(p[3], 0) << "pixel " << x << "," << y << " is not covered";
            sum = sum + Vec3f{p[0] / 255.f, p[1] / 255.f, p[2] / 255.f};
        }
    return sum * (1.f / float(n));
}

float maxDifference(const Vec3f& a, const Vec3f& b) {
    return std::max({std::fabs(a.x - b.x), std::fabs(a.y - b.y), std::fabs(a.z - b.z)});
}

// Eq. 12 for one layer over what lies behind it: c a + (1 - a) behind.
Vec3f over(const Vec3f& colour, float alpha, const Vec3f& behind) { return colour * alpha + behind * (1 - alpha); }

class Transparency : public test::GpuTest {
protected:
    // The GPU's and the CPU reference's images of `set` from 70 above.
    std::pair<Image, Image> renderBoth(const SurfelSet& set, const RenderSettings& settings, RendererOptions options = {}) {
        const Camera camera{{0, 0, 70}, {0, 0, 0}, {0, 1, 0}, 60};
        Image gpu = gpuRender(set, camera, kW, kH, settings, options);
        auto view = makeViewTransform(camera, set.origin, kW, kH);
        EXPECT_TRUE(view);
        return {gpu, view ? renderCpuReference(set, *view, settings) : Image{}};
    }
};

const Vec3f kRed{0.9f, 0.1f, 0.1f}, kGreen{0.1f, 0.8f, 0.2f}, kBlue{0.1f, 0.2f, 0.9f}, kWhite{1, 1, 1};

TEST_F(Transparency, StackedLayersBlendByEquationTwelve) {
    // Red (opacity 0.5) at z = 0 over green (0.5) at z = -10 over opaque blue
    // at z = -12, seen from above. Every layer has one colour and one opacity,
    // so its normalized colour and opacity are exact whatever the weights.
    SurfelSet set;
    addPlane(set, 0, kRed, 0.5f, 1);
    addPlane(set, -10, kGreen, 0.5f, 2);
    addPlane(set, -12, kBlue, 1.f, 3);
    ASSERT_TRUE(set.translucent);
    RenderSettings s;
    s.translucent = true;
    // Tolerance: 8-bit output rounds by half a step; the opacity, stored in
    // 8 bits, is 128/255 rather than 0.5 (0.2 % of a channel); 2/255 covers both.
    const float exact = 2.f / 255;

    // l = 4 >= 3 surfaces: eq. 12 over all three, back to front.
    s.layers = 4;
    const Vec3f three = over(kRed, 128 / 255.f, over(kGreen, 128 / 255.f, kBlue));
    auto [gpu4, cpu4] = renderBoth(set, s);
    EXPECT_LE(maxDifference(centreColour(gpu4), three), exact);
    EXPECT_LE(maxDifference(centreColour(cpu4), three), exact);
    RendererOptions quads;  // the other splat expansion has its own layered stage
    quads.expansion = Expansion::Quad;
    EXPECT_LE(maxDifference(centreColour(renderBoth(set, s, quads).first), three), exact);

    // l = 2: the two closest surfaces in depth (green and blue, 2 apart
    // against 10) merge into one layer: colours and opacities averaged by
    // their weights, which the equal sampling makes about equal (within 5 %
    // per pixel, so 0.03 on the mean colour).
    s.layers = 2;
    const Vec3f merged = (kGreen + kBlue) * 0.5f;
    const float mergedAlpha = (128 / 255.f + 1.f) / 2;
    const Vec3f two = over(kRed, 128 / 255.f, over(merged, mergedAlpha, kWhite));
    auto [gpu2, cpu2] = renderBoth(set, s);
    EXPECT_LE(maxDifference(centreColour(gpu2), two), 0.03f);
    EXPECT_LE(maxDifference(centreColour(cpu2), two), 0.03f);
    // Against l = 4, the white behind the merged layer shows: the merge is real.
    EXPECT_GT(maxDifference(centreColour(gpu2), three), 0.05f);

    // l = 1: all three merge (eq. 12 with one layer).
    s.layers = 1;
    const Vec3f all = (kRed + kGreen + kBlue) * (1.f / 3);
    const float allAlpha = (2 * 128 / 255.f + 1.f) / 3;
    auto [gpu1, cpu1] = renderBoth(set, s);
    EXPECT_LE(maxDifference(centreColour(gpu1), over(all, allAlpha, kWhite)), 0.03f);
    EXPECT_LE(maxDifference(centreColour(cpu1), over(all, allAlpha, kWhite)), 0.03f);
}

TEST_F(Transparency, ViewerOpacityMultipliesAndOpaqueLayersMatchTheOpaquePath) {
    // Opaque red at z = 0 over opaque blue at z = -10.
    SurfelSet set;
    addPlane(set, 0, kRed, 1.f, 1);
    addPlane(set, -10, kBlue, 1.f, 2);
    ASSERT_FALSE(set.translucent);
    RenderSettings opaque;
    auto [gpu, cpu] = renderBoth(set, opaque);
    EXPECT_LE(maxDifference(centreColour(gpu), kRed), 1.f / 255);

    // Drawn as translucent layers, an opaque front layer hides the rest:
    // the same image as the opaque path, to rounding.
    RenderSettings layered;
    layered.translucent = true;
    auto [gpuLayered, cpuLayered] = renderBoth(set, layered);
    size_t differ = 0;
    for (size_t i = 0; i < gpu.rgba.size(); ++i) differ += std::abs(int(gpu.rgba[i]) - int(gpuLayered.rgba[i])) > 1;
    EXPECT_EQ(differ, 0u);
    EXPECT_LE(maxDifference(centreColour(cpuLayered), kRed), 1.f / 255);

    // --opacity 0.5: red 0.5 over blue 0.5 over the white background.
    RenderSettings half;
    half.opacity = 0.5f;
    const Vec3f expected = over(kRed, 0.5f, over(kBlue, 0.5f, kWhite));
    auto [gpuHalf, cpuHalf] = renderBoth(set, half);
    EXPECT_LE(maxDifference(centreColour(gpuHalf), expected), 2.f / 255);
    EXPECT_LE(maxDifference(centreColour(cpuHalf), expected), 2.f / 255);
}

TEST_F(Transparency, GpuAndCpuReferenceAgreePerPixelWithEdgeAntialiasing) {
    // Two translucent discs, offset so that their silhouettes cross: every
    // pixel, edges included, from the GPU's depth peeling and the CPU's
    // A-buffer. Both keep the same surfaces per pixel here (2 <= l), so they
    // differ only by float rounding and the rasterizers' coverage of kernel
    // cut-offs: at most 3/255 per channel on all but 1 % of pixels.
    SurfelSet set;
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> jit(-0.3, 0.3);
    for (auto [cx, z, colour, opacity] : {std::tuple{-8.0, 0.0, kRed, 0.6f}, std::tuple{8.0, -15.0, kGreen, 0.7f}})
        for (double x = -30; x <= 30; x += 1)
            for (double y = -30; y <= 30; y += 1) {
                Vec3d p{x + jit(rng), y + jit(rng), z};
                if (p.x * p.x + p.y * p.y <= 900) addSurfel(set, p + Vec3d{cx, 0, 0}, {0, 0, 1}, 1.5f, colour, 1.f, 0, opacity);
            }
    RenderSettings s;
    s.translucent = true;
    s.edgeAA = true;
    auto [gpu, cpu] = renderBoth(set, s);
    size_t off = 0, partial = 0;
    for (size_t i = 0; i < gpu.rgba.size(); i += 4) {
        int worst = 0;
        for (int k = 0; k < 4; ++k) worst = std::max(worst, std::abs(int(gpu.rgba[i + k]) - int(cpu.rgba[i + k])));
        off += worst > 3;
        partial += gpu.rgba[i + 3] > 0 && gpu.rgba[i + 3] < 255;
    }
    EXPECT_LT(off, size_t(kW * kH / 100)) << "pixels where the GPU and the CPU reference differ by more than 3/255";
    EXPECT_GT(partial, size_t(kW * kH / 4)) << "translucent surfaces leave the composite partly transparent";
}

// --- Reading and storing opacity -------------------------------------------

// Decoded opacities of a set's leaves by position (x, y in hundredths), and
// the range of the resampled levels' ones; empty without the attribute.
struct StoredOpacity {
    std::map<std::pair<int, int>, int> leaves;
    int upperMin = 256, upperMax = -1;
};
StoredOpacity storedOpacity(const std::string& dir) {
    StoredOpacity out;
    auto set = TilesetReader::open(dir);
    EXPECT_TRUE(set.ok()) << set.status().message();
    if (!set.ok() || !set->info().attribute(kOpacityAttribute)) return out;
    for (const NodeRecord& n : set->nodes()) {
        auto block = set->readBlock(n);
        EXPECT_TRUE(block.ok()) << block.status().message();
        if (!block.ok()) continue;
        EXPECT_EQ(block->opacity.size(), block->size());
        for (size_t i = 0; i < block->opacity.size(); ++i) {
            if (n.flags & kFlagInputPoints) {
                const Vec3d p = surfelPosition(set->info(), n, *block, i);
                out.leaves[{int(std::lround(p.x * 100)), int(std::lround(p.y * 100))}] = block->opacity[i];
            } else {
                out.upperMin = std::min<int>(out.upperMin, block->opacity[i]);
                out.upperMax = std::max<int>(out.upperMax, block->opacity[i]);
            }
        }
    }
    return out;
}

// A 200 × 200 grid of points 0.01 apart in z = 0, as an ASCII PLY with the
// given alpha property line ("" for none) and value per point.
std::string gridPly(const std::string& alphaProperty, const std::function<std::string(int)>& alpha) {
    std::string ply = "ply\nformat ascii 1.0\nelement vertex 40000\nproperty float x\nproperty float y\nproperty float z\n" +
                      alphaProperty + "end_header\n";
    for (int i = 0; i < 40000; ++i)
        ply += std::to_string((i % 200) * 0.01) + " " + std::to_string((i / 200) * 0.01) + " 0" +
               (alphaProperty.empty() ? "" : " " + alpha(i)) + "\n";
    return ply;
}

TEST(Opacity, PlyAlphaRoundTripsAndResamplesWithinItsRange) {
    TempDir dir;
    test::writeFile(dir.file("a.ply"), gridPly("property uchar alpha\n", [](int i) { return std::to_string(40 + i % 200); }));
    auto r = test::run({test::binary("surfcast-build"), dir.file("a.ply"), "-o", dir.file("set"), "-q", "--capacity", "5000"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("attributes: opacity"), std::string::npos) << r.output;
    StoredOpacity got = storedOpacity(dir.file("set"));
    ASSERT_EQ(got.leaves.size(), 40000u);
    for (const auto& [xy, alpha] : got.leaves) ASSERT_EQ(alpha, 40 + xy.first) << "at x " << xy.first;
    // Resampled levels average the opacity (a Gaussian prefilter): within the inputs' range.
    ASSERT_GE(got.upperMax, 0) << "the set has resampled levels";
    EXPECT_GE(got.upperMin, 40);
    EXPECT_LE(got.upperMax, 239);

    // Float opacity in [0, 1] reads as it is; one outside fails, naming the
    // file and the vertex, and writes nothing.
    test::writeFile(dir.file("f.ply"), gridPly("property float opacity\n", [](int i) { return i == 777 ? "1.5" : "0.25"; }));
    r = test::run({test::binary("surfcast-build"), dir.file("f.ply"), "-o", dir.file("bad"), "-q"});
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("f.ply: vertex 777: opacity 1.5"), std::string::npos) << r.output;
    EXPECT_FALSE(std::filesystem::exists(dir.file("bad")));
}

TEST(Opacity, StoredOnlyWhereSomePointIsTranslucent) {
    TempDir dir;
    test::writeFile(dir.file("opaque.ply"), gridPly("property uchar alpha\n", [](int) { return "255"; }));
    auto r = test::run({test::binary("surfcast-build"), dir.file("opaque.ply"), "-o", dir.file("opaque"), "-q"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto opaque = TilesetReader::open(dir.file("opaque"));
    ASSERT_TRUE(opaque.ok());
    EXPECT_EQ(opaque->info().attribute(kOpacityAttribute), nullptr) << "an opaque set carries no opacity";

    // --opacity 0.5 applies to every point: 255 * 0.5 = 127.5 rounds to 128.
    r = test::run({test::binary("surfcast-build"), dir.file("opaque.ply"), "-o", dir.file("half"), "-q", "--opacity", "0.5"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    StoredOpacity half = storedOpacity(dir.file("half"));
    ASSERT_EQ(half.leaves.size(), 40000u);
    for (const auto& [xy, alpha] : half.leaves) ASSERT_EQ(alpha, 128);

    r = test::run({test::binary("surfcast-build"), dir.file("opaque.ply"), "-o", dir.file("x"), "-q", "--opacity", "2"});
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("--opacity needs a value in [0, 1]"), std::string::npos) << r.output;
}

TEST(Opacity, PcdAlphaOnlyWithReadAlpha) {
    TempDir dir;
    std::string pcd = "VERSION .7\nFIELDS x y z rgba\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 2500\nHEIGHT 1\n"
                      "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2500\nDATA ascii\n";
    for (int i = 0; i < 2500; ++i)
        pcd += std::to_string((i % 50) * 0.01) + " " + std::to_string((i / 50) * 0.01) + " 0 " +
               std::to_string(uint32_t(100) << 24 | 0x336699u) + "\n";
    test::writeFile(dir.file("c.pcd"), pcd);
    auto r = test::run({test::binary("surfcast-build"), dir.file("c.pcd"), "-o", dir.file("plain"), "-q"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_TRUE(storedOpacity(dir.file("plain")).leaves.empty()) << "the rgba alpha byte is ignored by default";
    r = test::run({test::binary("surfcast-build"), dir.file("c.pcd"), "-o", dir.file("alpha"), "-q", "--read-alpha"});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    StoredOpacity alpha = storedOpacity(dir.file("alpha"));
    ASSERT_EQ(alpha.leaves.size(), 2500u);
    for (const auto& [xy, a] : alpha.leaves) ASSERT_EQ(a, 100);
}

}  // namespace
}  // namespace surfcast
