// surfcast-view end to end: the real programs on a real scan (the bunny), the
// GPU path against the CPU reference, camera paths, bad arguments, and the
// window under Xvfb. SURFCAST_VALIDATION=1 is set for this test in the release
// suite (tests/CMakeLists.txt), so every GPU run also checks for zero
// validation errors there.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <nlohmann/json.hpp>
#include <sstream>

#include "image.h"
#include "test_support.h"
#include "tileset_reader.h"

namespace surfcast {
namespace {

using test::binary;
using test::jsonLines;
using test::run;
using test::TempDir;

const char* kBunnyCamera = "--camera=-0.017,0.13,0.2,-0.017,0.11,-0.002,0,1,0,40";

double meanAbsDiff(const Image& a, const Image& b, size_t* coverDiff) {
    double sum = 0;
    size_t n = 0;
    *coverDiff = 0;
    for (size_t i = 0; i < a.rgba.size(); i += 4) {
        bool ca = a.rgba[i] != 255 || a.rgba[i + 1] != 255 || a.rgba[i + 2] != 255;  // white background
        bool cb = b.rgba[i] != 255 || b.rgba[i + 1] != 255 || b.rgba[i + 2] != 255;
        *coverDiff += ca != cb;
        if (!ca && !cb) continue;
        for (int c = 0; c < 3; ++c) sum += std::abs(int(a.rgba[i + c]) - int(b.rgba[i + c])) / 255.0;
        n += 3;
    }
    return sum / std::max<size_t>(n, 1);
}

class ViewCli : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        if (!test::haveData()) return;
        dir_ = new TempDir;
        auto r = run({binary("surfcast-build"), "-q", test::dataFile("bunny.ply"), "--weights", "analytic", "-o", dir_->file("bunny")});
        ASSERT_EQ(r.exitCode, 0) << r.output;
    }
    static void TearDownTestSuite() {
        delete dir_;
        dir_ = nullptr;
    }
    void SetUp() override { REQUIRE_DATA(); }
    static std::string set() { return dir_->file("bunny"); }
    static TempDir* dir_;
};
TempDir* ViewCli::dir_ = nullptr;

TEST_F(ViewCli, BunnyGpuPerPixelEwaMatchesCpuReference) {
    TempDir out;
    auto gpu = run({binary("surfcast-view"), "--headless", set(), kBunnyCamera, "--size", "400x300", "--mode",
                    "ewa-pixel", "--out", out.file("gpu.png")});
    ASSERT_EQ(gpu.exitCode, 0) << gpu.output;
    auto cpu = run({binary("surfcast-view"), "--headless", set(), kBunnyCamera, "--size", "400x300", "--mode",
                    "cpu-reference", "--out", out.file("cpu.png")});
    ASSERT_EQ(cpu.exitCode, 0) << cpu.output;

    // The frame's JSON line: splats = every leaf's surfels, counted here from
    // the hierarchy independently of the renderer.
    auto reader = TilesetReader::open(set());
    ASSERT_TRUE(reader);
    size_t leafSurfels = 0;
    for (const auto& n : reader->nodes()) leafSurfels += n.childMask == 0 ? n.surfelCount : 0;
    auto lines = jsonLines(gpu.output);
    ASSERT_EQ(lines.size(), 1u) << gpu.output;
    EXPECT_EQ(lines[0]["splats"].get<size_t>(), leafSurfels);
    EXPECT_EQ(lines[0]["validation_errors"].get<int>(), 0);
    EXPECT_GT(lines[0]["gpu_ms"]["total"].get<double>(), 0);
    EXPECT_EQ(lines[0]["mode"], "ewa-pixel");

    auto a = readPng(out.file("gpu.png")), b = readPng(out.file("cpu.png"));
    ASSERT_TRUE(a && b);
    ASSERT_EQ(a->width, 400);
    ASSERT_EQ(a->height, 300);
    size_t coverDiff = 0;
    double mean = meanAbsDiff(*a, *b, &coverDiff);
    // The threshold of render_test's checkerboard (docs/RENDERER.md): shading
    // (Lambert) varies slowly, so the same bound holds; the outline differs by
    // the silhouette fringe, a one-pixel band.
    EXPECT_LT(mean, 0.01);
    size_t covered = lines[0]["pixels_covered"].get<size_t>();
    EXPECT_GT(covered, 400u * 300 / 2);
    EXPECT_LT(coverDiff, covered / 20);
}

TEST_F(ViewCli, CameraPathWritesOnePngAndOneJsonLinePerFrame) {
    TempDir out;
    test::writeFile(out.file("path.json"), R"({"frames": [
        {"eye": [-0.017, 0.13, 0.25], "target": [-0.017, 0.11, 0], "up": [0, 1, 0], "fov": 40},
        {"eye": [0.2, 0.13, 0.1], "target": [-0.017, 0.11, 0], "up": [0, 1, 0]},
        {"eye": [-0.2, 0.3, 0.1], "target": [-0.017, 0.11, 0], "up": [0, 1, 0], "fov": 60}]})");
    for (const char* mode : {"points", "circles", "ewa-surfel"}) {
        auto r = run({binary("surfcast-view"), "--headless", set(), "--camera-path", out.file("path.json"), "--size",
                      "160x120", "--mode", mode, "--out", out.file(std::string(mode) + ".png")});
        ASSERT_EQ(r.exitCode, 0) << r.output;
        auto lines = jsonLines(r.output);
        ASSERT_EQ(lines.size(), 3u) << r.output;
        for (size_t f = 0; f < 3; ++f) {
            std::string path = out.file(std::string(mode) + "_000" + std::to_string(f) + ".png");
            EXPECT_EQ(lines[f]["out"], path);
            EXPECT_EQ(lines[f]["frame"].get<size_t>(), f);
            auto img = readPng(path);
            ASSERT_TRUE(img) << img.status().message();
            EXPECT_GT(lines[f]["pixels_covered"].get<size_t>(), 500u) << mode;
        }
    }
    // Without --camera the view frames the whole set: something is drawn.
    auto r = run({binary("surfcast-view"), "--headless", set(), "--size", "160x120", "--out", out.file("auto.png")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_GT(jsonLines(r.output).at(0)["pixels_covered"].get<size_t>(), 200u);
}

TEST_F(ViewCli, BadArgumentsAndInputsGiveClearErrors) {
    TempDir out;
    struct Case {
        std::vector<std::string> args;
        int exit;
        std::string message;
    };
    std::vector<Case> cases = {
        {{"--headless", out.file("nope")}, 1, "nope"},
        {{"--headless", set(), "--camera", "1,2,3"}, 2, "--camera"},
        {{"--headless", set(), "--camera", "0,0,0,0,0,0,0,0,1,45"}, 2, "coincide"},
        {{"--headless", set(), "--mode", "splat"}, 2, "--mode"},
        {{"--headless", set(), "--size", "0x10"}, 2, "--size"},
        {{"--headless", set(), "--level", "9"}, 1, "level 9"},
        {{"--headless", set(), "--camera-path", out.file("missing.json")}, 2, "missing.json"},
        {{"--headless"}, 2, "no tile set"},
        {{"--headless", set(), "--frobnicate"}, 2, "--frobnicate"},
        {{"--headless", set(), "--out", out.file("no/such/dir/x.png")}, 1, "x.png"},
        {{"--headless", set(), "--color-by", "height"}, 2, "--color-by"},
        {{"--headless", set(), "--color-by", "classification"}, 1, "no classification"},
        {{"--headless", set(), "--hide-classes", "2,300"}, 2, "--hide-classes"},
        {{"--headless", set(), "--clip", "0,0,0,1,1"}, 2, "six numbers"},
        {{"--headless", set(), "--clip", "0,0,0,1,nan,1"}, 2, "'nan' is not a number"},
        {{"--headless", set(), "--clip", "0,2,0,1,1,1"}, 2, "maximum on axis y"},
        {{"--headless", set(), "--follow", "2"}, 2, "it needs --lod"},
        {{"--headless", set(), "--lod", "1", "--follow", "0"}, 2, "--follow wants a positive number"},
    };
    for (const auto& c : cases) {
        std::vector<std::string> args = {binary("surfcast-view")};
        args.insert(args.end(), c.args.begin(), c.args.end());
        auto r = run(args);
        EXPECT_EQ(r.exitCode, c.exit) << c.args.back() << ": " << r.output;
        EXPECT_NE(r.output.find(c.message), std::string::npos) << r.output;
    }
    auto help = run({binary("surfcast-view"), "--help"});
    EXPECT_EQ(help.exitCode, 0);
    EXPECT_NE(help.output.find("--mode"), std::string::npos);
}

TEST_F(ViewCli, WindowRendersUnderXvfbLikeHeadless) {
    TempDir out;
    auto window = run({"/usr/bin/xvfb-run", "-a", "-s", "-screen 0 640x480x24", binary("surfcast-view"), set(), kBunnyCamera,
                       "--size", "320x240", "--frames", "3", "--screenshot", out.file("window.png")});
    ASSERT_EQ(window.exitCode, 0) << window.output;
    auto headless = run({binary("surfcast-view"), "--headless", set(), kBunnyCamera, "--size", "320x240", "--out",
                         out.file("headless.png")});
    ASSERT_EQ(headless.exitCode, 0) << headless.output;
    auto a = readPng(out.file("window.png")), b = readPng(out.file("headless.png"));
    ASSERT_TRUE(a) << a.status().message();
    ASSERT_TRUE(b);
    ASSERT_EQ(a->width, 320);
    EXPECT_EQ(a->rgba, b->rgba) << "the window's frame is the headless frame of the same camera";
}

}  // namespace
}  // namespace surfcast

namespace surfcast {
namespace {

// These renders use a magenta background, which no colour mode produces
// (intensity reaches white, elevation and classes reach dark).
const char* kMagenta = "--background=1,0,1";
bool isCovered(const Image& a, size_t i) { return !(a.rgba[i] == 255 && a.rgba[i + 1] == 0 && a.rgba[i + 2] == 255); }
size_t covered(const Image& a) {
    size_t n = 0;
    for (size_t i = 0; i < a.rgba.size(); i += 4) n += isCovered(a, i);
    return n;
}
// Pixels covered in one image and not the other, and the mean absolute colour
// difference where both are covered.
size_t coverageDiff(const Image& a, const Image& b, double* colorDiff = nullptr) {
    size_t diff = 0, both = 0;
    double sum = 0;
    for (size_t i = 0; i < a.rgba.size(); i += 4) {
        diff += isCovered(a, i) != isCovered(b, i);
        if (!isCovered(a, i) || !isCovered(b, i)) continue;
        ++both;
        for (int c = 0; c < 3; ++c) sum += std::abs(int(a.rgba[i + c]) - int(b.rgba[i + c])) / (3 * 255.0);
    }
    if (colorDiff) *colorDiff = sum / double(std::max<size_t>(both, 1));
    return diff;
}
// Pixels covered in only one image, or in both with colours more than 0.1
// apart (mean over channels): what a viewer sees differ.
size_t differingPixels(const Image& a, const Image& b) {
    size_t n = 0;
    for (size_t i = 0; i < a.rgba.size(); i += 4) {
        int d = 0;
        for (int c = 0; c < 3; ++c) d += std::abs(int(a.rgba[i + c]) - int(b.rgba[i + c]));
        n += isCovered(a, i) != isCovered(b, i) || (isCovered(a, i) && d > 0.1 * 3 * 255);
    }
    return n;
}

// Autzen (RGB, intensity, classes 1 and 2, returns) seen from above.
const char* kAutzenCamera = "--camera=636590,848700,1400,636590,849216,463,0,1,0,45";

TEST_F(ViewCli, ColorByModesRenderAndDiffer) {
    TempDir out;
    auto b = run({binary("surfcast-build"), "-q", test::dataFile("autzen_trim.las"), "-o", out.file("autzen")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    std::vector<std::string> modes = {"gray", "rgb", "intensity", "elevation", "classification", "return"};
    std::vector<Image> images;
    for (const std::string& m : modes) {
        std::vector<std::string> args = {binary("surfcast-view"), "--headless", out.file("autzen"), kAutzenCamera,
                                         kMagenta, "--size", "320x240", "--out", out.file(m + ".png")};
        if (m == "gray") args.insert(args.end(), {"--color", "0.8,0.8,0.8"});
        else args.insert(args.end(), {"--color-by", m});
        auto r = run(args);
        ASSERT_EQ(r.exitCode, 0) << m << ": " << r.output;
        auto img = readPng(out.file(m + ".png"));
        ASSERT_TRUE(img.ok());
        images.push_back(*img);
    }
    // Same splats, so the same coverage (up to the odd pixel at the coverage
    // threshold: lavapipe's accumulation order varies between runs); colours
    // differ between every pair by far more than that noise.
    for (size_t i = 0; i < images.size(); ++i)
        for (size_t j = i + 1; j < images.size(); ++j) {
            double d = 0;
            size_t coverDiff = coverageDiff(images[i], images[j], &d);
            EXPECT_LE(coverDiff, covered(images[i]) / 1000) << modes[i] << " vs " << modes[j];
            EXPECT_GT(d, 0.03) << modes[i] << " vs " << modes[j];
        }
}

// --hide-classes 2 against a set built from autzen without its class-2 points.
// The leaves hold the same class-1 points in both, all drawn in class 1's one
// palette colour, so the images can differ only where splat sizes differ: h
// and the per-surfel radii come from neighbours, and the other set lacks the
// class-2 ones, so class-1 splats bordering ground grow there. That changes
// coverage in a band about one splat wide along the class boundary: measured
// 1,810 pixels against 11,158 that showing class 2 changes (brown ground, and
// its coverage), of 28,732 covered. The bound is a fifth of the latter.
// Edge antialiasing is off: it blends that band's border pixels with the
// background by their differing coverage, and this test is about what hiding
// draws.
TEST_F(ViewCli, HiddenClassLeavesWhatAFilteredBuildShows) {
    TempDir out;
    const std::string src = test::readFile(test::dataFile("autzen_trim.las"));
    uint32_t offset;
    std::memcpy(&offset, src.data() + 96, 4);
    std::string kept = src.substr(0, offset);
    uint32_t count = 0;
    for (size_t i = 0; i < 110000; ++i) {
        const char* r = src.data() + offset + i * 34;
        if ((uint8_t(r[15]) & 31) == 2) continue;
        kept.append(r, 34);
        ++count;
    }
    std::memcpy(kept.data() + 107, &count, 4);
    test::writeFile(out.file("no2.las"), kept);
    ASSERT_GT(count, 10000u);
    ASSERT_LT(count, 100000u);
    // The filtered set has one class: it stores classification only on request.
    for (auto [in, name] : {std::pair{test::dataFile("autzen_trim.las"), "all"}, std::pair{out.file("no2.las"), "no2"}}) {
        auto b = run({binary("surfcast-build"), "-q", in, "-o", out.file(name), "--attributes", "all"});
        ASSERT_EQ(b.exitCode, 0) << b.output;
    }
    auto render = [&](const std::string& set, const std::string& png, std::vector<std::string> extra) {
        std::vector<std::string> args = {binary("surfcast-view"), "--headless", set, kAutzenCamera, "--size", "320x240",
                                         kMagenta, "--color-by", "classification", "--edge-aa", "off", "--out", out.file(png)};
        args.insert(args.end(), extra.begin(), extra.end());
        auto r = run(args);
        EXPECT_EQ(r.exitCode, 0) << r.output;
        auto img = readPng(out.file(png));
        EXPECT_TRUE(img.ok());
        return img ? *img : Image{};
    };
    Image hidden = render(out.file("all"), "hidden.png", {"--hide-classes", "2"});
    Image shown = render(out.file("all"), "shown.png", {});
    Image filtered = render(out.file("no2"), "filtered.png", {});
    Image only = render(out.file("all"), "only1.png", {"--classes", "1"});
    const size_t hiddenDiff = differingPixels(hidden, filtered), shownDiff = differingPixels(shown, filtered);
    // --classes 1 is --hide-classes 2 on this set (up to threshold noise).
    EXPECT_LE(coverageDiff(hidden, only), covered(only) / 1000);
    EXPECT_GT(shownDiff, covered(filtered) / 5) << "class 2 shows little in this view";
    EXPECT_LT(hiddenDiff * 5, shownDiff) << "hidden " << hiddenDiff << ", shown " << shownDiff;
    std::printf("pixels differing from the filtered build: hidden %zu, shown %zu (of %zu covered)\n", hiddenDiff,
                shownDiff, covered(filtered));
}

}  // namespace
}  // namespace surfcast
