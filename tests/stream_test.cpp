// Streaming (client/stream/streamer): a tile set streamed over HTTP from the
// real server on loopback converges to the very image rendered from the local
// folder, downloading no more than the set holds (from surfcast-serve with
// batched requests; nginx and TLS are in remote_host_test.cpp); a tight GPU
// budget evicts and still converges; a host's own VkDevice draws the same
// image; a colouring change re-decodes what is resident without fetching.
// Faults (restarts, stalls, corrupt or refused responses, budgets) are in
// stream_faults_test.cpp.

#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <thread>

#include "context.h"
#include "stream_support.h"
#include "streamer.h"
#include "surfcast_client.h"
#include "test_support.h"

namespace surfcast {
namespace {

using test::binary;
using test::expectStreamsLikeLocal;
using test::lastLine;
using test::run;
using test::TempDir;

using test::startServer;


TEST(Stream, OverHttpConvergesToTheLocalImage) {
    TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = test::buildScene(dir.file("sets/scene"), 150000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    test::Child server;
    const std::string origin = startServer(&server, dir.file("sets"));
    ASSERT_FALSE(origin.empty()) << server.log;
    const std::string url = origin + "/sets/scene";

    for (const char* camera : {"--camera=3,-6,2,0,0,0.5,0,0,1,50", "--camera=0,0,1,5,5,0.5,0,0,1,70"}) {
        auto last = expectStreamsLikeLocal(url, dir.file("sets/scene"), camera, dir);
        ASSERT_TRUE(last.is_object());
        uint64_t blocks = std::filesystem::file_size(dir.file("sets/scene/blocks.bin"));
        EXPECT_GT(last["bytes_downloaded"].get<uint64_t>(), 0u);
        EXPECT_LE(last["bytes_downloaded"].get<uint64_t>(), blocks);
    }
    // The client batched its node requests (the server's POST .../batch).
    httplib::Client metrics(origin);
    auto m = metrics.Get("/metrics");
    ASSERT_TRUE(m && m->status == 200);
    EXPECT_NE(m->body.find("surfcast_requests_total{route=\"batch\",status=\"200\"}"), std::string::npos) << m->body;
    ::kill(server.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(server.pid), 0);
}

TEST(Stream, TightGpuBudgetEvictsAndStillConverges) {
    // Four views (the last repeats the first) that together need more than
    // 8 MiB of surfels: the stream evicts least recently used nodes, never
    // holds more than the budget, and every view converges. What a view
    // converges to does not depend on what was resident before: the repeated
    // view gives the same image, and a view the budgets do not limit gives
    // the image of an unlimited GPU budget.
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 300000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    test::writeFile(dir.file("path.json"), R"({"frames": [
        {"eye": [3, -6, 2], "target": [0, 0, 0.5], "up": [0, 0, 1], "fov": 50},
        {"eye": [-4, 5, 1.5], "target": [0, 0, 0.5], "up": [0, 0, 1], "fov": 50},
        {"eye": [0, 0, 1], "target": [5, 5, 0.5], "up": [0, 0, 1], "fov": 70},
        {"eye": [3, -6, 2], "target": [0, 0, 0.5], "up": [0, 0, 1], "fov": 50}]})");
    const size_t budget = 8 << 20, splats = 100000;
    auto tight = run({binary("surfcast-view"), "--headless", dir.file("scene"), "--camera-path", dir.file("path.json"),
                      "--lod", "1", "--size", "320x180", "--gpu-budget", "8", "--splat-budget", std::to_string(splats),
                      "--max-wait", "60", "--out", dir.file("tight.png")});
    ASSERT_EQ(tight.exitCode, 0) << tight.output;
    auto roomy = run({binary("surfcast-view"), "--headless", dir.file("scene"), "--camera-path", dir.file("path.json"),
                      "--lod", "1", "--size", "320x180", "--splat-budget", std::to_string(splats), "--out",
                      dir.file("roomy.png")});
    ASSERT_EQ(roomy.exitCode, 0) << roomy.output;
    auto lines = test::jsonLines(tight.output);
    ASSERT_FALSE(lines.empty());
    std::vector<nlohmann::json> converged;
    bool limited = false;
    for (const auto& l : lines) {
        EXPECT_LE(l["resident_bytes"].get<size_t>(), budget) << l.dump();
        EXPECT_LE(l["splats"].get<size_t>(), splats) << l.dump();
        if (l["converged"].get<bool>()) converged.push_back(l);
        limited |= l["budget_limited"].get<size_t>() > 0;
    }
    ASSERT_EQ(converged.size(), 4u) << tight.output;
    EXPECT_TRUE(limited) << "the budgets should bind on some of these views";
    EXPECT_GT(lines.back()["evictions"].get<size_t>(), 0u) << "8 MiB should not hold every view";
    auto frame = [&](const std::string& run, int f) { return test::readFile(dir.file(run + "_000" + std::to_string(f) + ".png")); };
    EXPECT_TRUE(frame("tight", 3) == frame("tight", 0)) << "the repeated view converged to another image";
    size_t unlimited = 0;
    for (int f = 0; f < 4; ++f) {
        if (converged[size_t(f)]["budget_limited"].get<size_t>() > 0) continue;
        ++unlimited;
        EXPECT_TRUE(frame("tight", f) == frame("roomy", f)) << "frame " << f << " differs under the tight GPU budget";
    }
    EXPECT_GT(unlimited, 0u) << "one view should fit the budgets";
}

// Updates `client` until converged (60 s at most); the nodes uploaded on the way.
size_t convergeClient(SurfcastClient& client, const Camera& camera, ClientFrame* last, int width = 240, int height = 180) {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    size_t uploaded = 0;
    while (std::chrono::steady_clock::now() < deadline) {
        auto frame = client.update(camera, width, height);
        EXPECT_TRUE(frame) << frame.status().message();
        if (!frame) break;
        uploaded += frame->uploaded;
        *last = *frame;
        if (frame->converged) return uploaded;
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ADD_FAILURE() << "did not converge";
    return uploaded;
}

Image clientImage(SurfcastClient& client, const RenderSettings* settings = nullptr) {
    auto image = client.renderImage(settings ? *settings : client.defaultSettings());
    EXPECT_TRUE(image) << image.status().message();
    return image ? *image : Image{};
}

// Streams `location` through a client until converged; the rendered image.
Image streamImage(gpu::Context& ctx, const std::string& location, const Camera& camera) {
    auto client = SurfcastClient::open(ctx, location, ClientOptions{});
    EXPECT_TRUE(client) << client.status().message();
    if (!client) return {};
    ClientFrame last;
    convergeClient(**client, camera, &last, 200, 150);
    return clientImage(**client);
}

// autzen_trim.las built into dir/autzen with nodes of at most `capacity` surfels.
void buildAutzen(const TempDir& dir, const char* capacity) {
    auto b = run({binary("surfcast-build"), "-q", test::dataFile("autzen_trim.las"), "-o", dir.file("autzen"), "--capacity",
                  capacity});
    ASSERT_EQ(b.exitCode, 0) << b.output;
}

// The host fills Vulkan's structures as hosts do, `VkFooInfo info{VK_STRUCTURE_TYPE_...};`
// (the rest zero), which -Wextra's missing-field-initializers flags. A pragma,
// not a command-line -Wno-: clang takes the warning state of the shared
// precompiled header (tests/CMakeLists.txt) over the command line's.
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
TEST(Stream, HostOwnedDeviceDrawsTheSameImage) {
    // A host application's own instance and device, made with plain Vulkan,
    // handed to the client (gpu::wrapContext): the same image as the client's
    // own context on the same device, and the host's device outlives it.
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 60000);
    ASSERT_EQ(b.exitCode, 0) << b.output;
    auto camera = parseCamera("3,-6,2,0,0,0.5,0,0,1,50");
    ASSERT_TRUE(camera);

    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.apiVersion = VK_API_VERSION_1_3;
    VkInstanceCreateInfo instanceInfo{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    instanceInfo.pApplicationInfo = &app;
    VkInstance instance = VK_NULL_HANDLE;
    ASSERT_EQ(vkCreateInstance(&instanceInfo, nullptr, &instance), VK_SUCCESS);
    uint32_t count = 0;
    vkEnumeratePhysicalDevices(instance, &count, nullptr);
    std::vector<VkPhysicalDevice> devices(count);
    vkEnumeratePhysicalDevices(instance, &count, devices.data());
    // The first Vulkan 1.3 device with a graphics queue.
    int chosen = -1;
    uint32_t family = 0;
    for (size_t i = 0; i < devices.size() && chosen < 0; ++i) {
        VkPhysicalDeviceProperties props;
        vkGetPhysicalDeviceProperties(devices[i], &props);
        if (props.apiVersion < VK_API_VERSION_1_3) continue;
        uint32_t n = 0;
        vkGetPhysicalDeviceQueueFamilyProperties(devices[i], &n, nullptr);
        std::vector<VkQueueFamilyProperties> families(n);
        vkGetPhysicalDeviceQueueFamilyProperties(devices[i], &n, families.data());
        for (uint32_t f = 0; f < n && chosen < 0; ++f)
            if (families[f].queueFlags & VK_QUEUE_GRAPHICS_BIT) {
                chosen = int(i);
                family = f;
            }
    }
    ASSERT_GE(chosen, 0) << "no Vulkan 1.3 device";
    VkPhysicalDeviceFeatures supported;
    vkGetPhysicalDeviceFeatures(devices[size_t(chosen)], &supported);
    VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    f13.dynamicRendering = VK_TRUE;
    f13.synchronization2 = VK_TRUE;
    VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f13};
    features.features.geometryShader = supported.geometryShader;
    float priority = 1;
    VkDeviceQueueCreateInfo queueInfo{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queueInfo.queueFamilyIndex = family;
    queueInfo.queueCount = 1;
    queueInfo.pQueuePriorities = &priority;
    VkDeviceCreateInfo deviceInfo{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &features};
    deviceInfo.queueCreateInfoCount = 1;
    deviceInfo.pQueueCreateInfos = &queueInfo;
    VkDevice device = VK_NULL_HANDLE;
    ASSERT_EQ(vkCreateDevice(devices[size_t(chosen)], &deviceInfo, nullptr, &device), VK_SUCCESS);
    VkQueue queue = VK_NULL_HANDLE;
    vkGetDeviceQueue(device, family, 0, &queue);

    Image hosted;
    {
        auto ctx = gpu::wrapContext({instance, devices[size_t(chosen)], device, family, queue, bool(supported.geometryShader)});
        ASSERT_TRUE(ctx) << ctx.status().message();
        hosted = streamImage(**ctx, dir.file("scene"), *camera);
        gpu::destroyContext(*ctx);
    }
    // The host's device is still usable after the client and context are gone.
    EXPECT_EQ(vkDeviceWaitIdle(device), VK_SUCCESS);
    vkDestroyDevice(device, nullptr);
    vkDestroyInstance(instance, nullptr);

    auto own = gpu::createContext({std::to_string(chosen), false, {}, false});
    ASSERT_TRUE(own) << own.status().message();
    Image owned = streamImage(**own, dir.file("scene"), *camera);
    gpu::destroyContext(*own);
    ASSERT_EQ(hosted.width, 200u);
    EXPECT_TRUE(hosted.rgba == owned.rgba) << "the host's device drew another image";
}

TEST(Stream, ColourKeyStepsThroughTheModesTheSetHas) {
    // A set with intensity and classes but no colour or returns: C goes
    // intensity -> elevation -> classification -> intensity; Auto is intensity.
    TilesetInfo info;
    info.attributes = {{"position", "float32", 3}, {"intensity", "uint16", 1, 0, "continuous"},
                       {"classification", "uint8", 1, 0, "categorical"}};
    EXPECT_EQ(nextColorBy(ColorBy::Auto, info), ColorBy::Elevation);
    EXPECT_EQ(nextColorBy(ColorBy::Elevation, info), ColorBy::Classification);
    EXPECT_EQ(nextColorBy(ColorBy::Classification, info), ColorBy::Intensity);
    EXPECT_EQ(nextColorBy(ColorBy::Rgb, info), ColorBy::Elevation) << "a mode the set lacks steps from Auto's";
    info.colorBits = 8;
    EXPECT_EQ(nextColorBy(ColorBy::Classification, info), ColorBy::Rgb);
    EXPECT_EQ(nextColorBy(ColorBy::Auto, info), ColorBy::Intensity);
    TilesetInfo bare;  // positions only: elevation is all there is
    EXPECT_EQ(nextColorBy(ColorBy::Elevation, bare), ColorBy::Elevation);
}

TEST(Stream, ColoringChangesWithoutFetchingAgain) {
    // autzen (RGB, intensity, classes 1 and 2) streamed in colour, then
    // switched to classes with ground hidden: every drawn node is uploaded
    // again, nothing is fetched, and the converged image is the one a client
    // opened with that colouring draws. Switching back gives the first image.
    TempDir dir;
    ASSERT_NO_FATAL_FAILURE(buildAutzen(dir, "4000"));
    auto camera = parseCamera("636590,848700,1400,636590,849216,463,0,1,0,45");
    ASSERT_TRUE(camera);
    auto ctx = gpu::createContext({});
    ASSERT_TRUE(ctx) << ctx.status().message();
    Coloring rgb, classes;
    rgb.by = ColorBy::Rgb;
    classes.by = ColorBy::Classification;
    classes.hidden[2] = true;
    Image inColour, recoloured, opened, back;
    ClientFrame before, after;
    size_t reuploaded = 0;
    {
        ClientOptions options;
        options.coloring = rgb;
        auto client = SurfcastClient::open(**ctx, dir.file("autzen"), options);
        ASSERT_TRUE(client) << client.status().message();
        convergeClient(**client, *camera, &before);
        inColour = clientImage(**client);
        ASSERT_GT(before.nodes, 1u);
        EXPECT_GT(before.stream.keptBytes, 0u);
        EXPECT_LE(before.stream.keptBytes, (*client)->info().blocksBytes);

        const RenderSettings colourSettings = (*client)->defaultSettings();
        ASSERT_TRUE((*client)->setColoring(classes));
        EXPECT_EQ((*client)->coloring().by, ColorBy::Classification);
        EXPECT_EQ(colourSettings.shading, Shading::Unlit);
        EXPECT_EQ((*client)->defaultSettings().shading, Shading::Lambert) << "class colours are shaded";
        EXPECT_TRUE(clientImage(**client, &colourSettings).rgba == inColour.rgba)
            << "nothing changes before an update hands over the new surfels";
        reuploaded = convergeClient(**client, *camera, &after);
        recoloured = clientImage(**client);
        EXPECT_EQ(after.stream.recoloring, 0u);

        ASSERT_TRUE((*client)->setColoring(rgb));
        ClientFrame again;
        convergeClient(**client, *camera, &again);
        back = clientImage(**client);
        EXPECT_EQ(again.stream.requests, before.stream.requests);
    }
    std::printf("recoloured %zu nodes (%zu drawn): kept %zu bytes of blocks for %zu resident bytes\n", reuploaded,
                before.nodes, before.stream.keptBytes, before.stream.residentBytes);
    EXPECT_GE(reuploaded, before.nodes) << "every drawn node is decoded and uploaded again";
    EXPECT_EQ(after.nodes, before.nodes);
    EXPECT_EQ(after.stream.requests, before.stream.requests) << "recolouring fetched blocks";
    EXPECT_EQ(after.stream.bytesDownloaded, before.stream.bytesDownloaded);
    EXPECT_EQ(after.stream.nodesFetched, before.stream.nodesFetched);
    EXPECT_LT(after.splats, before.splats) << "hidden ground surfels are not drawn";
    {
        ClientOptions options;
        options.coloring = classes;
        auto client = SurfcastClient::open(**ctx, dir.file("autzen"), options);
        ASSERT_TRUE(client) << client.status().message();
        ClientFrame frame;
        convergeClient(**client, *camera, &frame);
        opened = clientImage(**client);
        EXPECT_EQ(frame.splats, after.splats);
    }
    EXPECT_TRUE(recoloured.rgba == opened.rgba) << "recoloured differs from a client opened with that colouring";
    EXPECT_TRUE(back.rgba == inColour.rgba) << "switching back did not give the first image";
    EXPECT_FALSE(recoloured.rgba == inColour.rgba);

    // The kept blocks count against the block cache's budget. With a
    // block cache of a third of what the view's blocks take, the cache stays
    // within it, and the recolour fetches the blocks that went (at most the
    // resident nodes', no more bytes than the view fetched) and converges to the same image.
    {
        ClientOptions options;
        options.coloring = rgb;
        options.blockCache = before.stream.keptBytes / 3;
        auto client = SurfcastClient::open(**ctx, dir.file("autzen"), options);
        ASSERT_TRUE(client) << client.status().message();
        ClientFrame first, recolouredFrame;
        convergeClient(**client, *camera, &first);
        EXPECT_LE(first.stream.keptBytes, options.blockCache);
        EXPECT_EQ(first.stream.bytesDownloaded, before.stream.bytesDownloaded);
        ASSERT_TRUE((*client)->setColoring(classes));
        convergeClient(**client, *camera, &recolouredFrame);
        EXPECT_TRUE(clientImage(**client).rgba == opened.rgba) << "recoloured through refetches differs";
        EXPECT_GT(recolouredFrame.stream.refetched, 0u);
        EXPECT_LE(recolouredFrame.stream.refetched, first.stream.resident);
        EXPECT_GT(recolouredFrame.stream.bytesDownloaded, first.stream.bytesDownloaded);
        EXPECT_LE(recolouredFrame.stream.bytesDownloaded - first.stream.bytesDownloaded, first.stream.bytesDownloaded);
        EXPECT_LE(recolouredFrame.stream.keptBytes, options.blockCache);
        std::printf("block cache %zu bytes: %zu blocks fetched again to recolour\n", options.blockCache,
                    recolouredFrame.stream.refetched);
    }

    // A mode the set lacks is an error, and changes nothing.
    auto scene = test::buildScene(dir.file("scene"), 20000);
    ASSERT_EQ(scene.exitCode, 0) << scene.output;
    auto client = SurfcastClient::open(**ctx, dir.file("scene"), {});
    ASSERT_TRUE(client) << client.status().message();
    Status s = (*client)->setColoring(classes);
    EXPECT_FALSE(s);
    EXPECT_NE(s.message().find("classification"), std::string::npos) << s.message();
    EXPECT_EQ((*client)->coloring().by, ColorBy::Auto);
    client->reset();
    gpu::destroyContext(*ctx);
}

TEST(Stream, ColoringChangesWhileStreamingAndEvicting) {
    // Colouring changes while nodes are fetched, decoded, handed over and
    // evicted under a GPU budget smaller than the set: a block decoded with
    // an old colouring never stays on screen, and each time the view
    // converges to the image of a client opened with the last colouring.
    // Each round lands the change at another moment of the close view's
    // fetching and decoding (after 0 to 12 ms).
    TempDir dir;
    ASSERT_NO_FATAL_FAILURE(buildAutzen(dir, "2000"));
    auto overview = parseCamera("636590,848700,1400,636590,849216,463,0,1,0,45");
    auto close = parseCamera("636500,849100,700,636600,849250,430,0,0,1,40");
    ASSERT_TRUE(overview && close);
    auto ctx = gpu::createContext({});
    ASSERT_TRUE(ctx) << ctx.status().message();
    std::vector<Coloring> sequence(4);
    sequence[0].by = ColorBy::Elevation;
    sequence[1].by = ColorBy::Classification;
    sequence[1].hidden[2] = true;
    sequence[2].by = ColorBy::Intensity;
    sequence[3].by = ColorBy::Return;
    sequence[3].hidden[1] = true;
    ClientOptions options;
    // Less than the overview needs (about 7 MiB) and more than the close view
    // (under 3 MiB): the overview converges within the budget, and its nodes
    // make room for the close view's.
    options.gpuBudget = 6 << 20;
    options.decoders = 1;
    // What a client opened with each colouring converges to at the close view.
    std::vector<Image> expected;
    for (const Coloring& c : sequence) {
        options.coloring = c;
        auto client = SurfcastClient::open(**ctx, dir.file("autzen"), options);
        ASSERT_TRUE(client) << client.status().message();
        ClientFrame frame;
        convergeClient(**client, *close, &frame);
        EXPECT_EQ(frame.lod.budgetLimited, 0u) << "the close view alone should fit the budget";
        expected.push_back(clientImage(**client));
    }
    options.coloring = {};
    auto client = SurfcastClient::open(**ctx, dir.file("autzen"), options);
    ASSERT_TRUE(client) << client.status().message();
    ClientFrame frame;
    for (int round = 0; round < 8; ++round) {
        const size_t c = size_t(round) % sequence.size();
        convergeClient(**client, *overview, &frame);
        ASSERT_TRUE((*client)->update(*close, 240, 180));
        std::this_thread::sleep_for(std::chrono::milliseconds(round * 3 / 2));
        ASSERT_TRUE((*client)->setColoring(sequence[c]));
        convergeClient(**client, *close, &frame);
        EXPECT_TRUE(clientImage(**client).rgba == expected[c].rgba)
            << "round " << round << ": the view converged to another image than a fresh client's";
    }
    std::printf("%zu evictions; %zu nodes drawn in the close view\n", frame.stream.evictions, frame.nodes);
    EXPECT_GT(frame.stream.evictions, 0u) << "the budget should not hold both views";
    client->reset();
    gpu::destroyContext(*ctx);
}

TEST(Stream, WindowStreamsUnderXvfb) {
    TempDir dir;
    auto b = test::buildScene(dir.file("scene"), 100000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    const char* camera = "--camera=3,-6,2,0,0,0.5,0,0,1,50";
    // --frames counts converged frames: the screenshot is the converged view.
    auto window = run({"/usr/bin/xvfb-run", "-a", "-s", "-screen 0 640x480x24", binary("surfcast-view"), dir.file("scene"),
                       camera, "--lod", "1", "--size", "200x150", "--frames", "2", "--screenshot", dir.file("window.png")});
    ASSERT_EQ(window.exitCode, 0) << window.output;
    auto headless = run({binary("surfcast-view"), "--headless", dir.file("scene"), camera, "--lod", "1", "--size", "200x150",
                         "--out", dir.file("headless.png")});
    ASSERT_EQ(headless.exitCode, 0) << headless.output;
    EXPECT_TRUE(test::readFile(dir.file("window.png")) == test::readFile(dir.file("headless.png")))
        << "the window's converged frame differs from the headless one";
}

TEST(Stream, WindowKeysRecolourTheStream) {
    // Real key presses (xdotool) in the streaming window under Xvfb: C steps
    // from autzen's RGB to intensity, G hides ground; after each, once the
    // title says the view is converged in that colouring, P writes a
    // screenshot. Each equals the headless render of that colouring, and
    // nothing was fetched twice (the title's megabytes stay those of the set).
    TempDir dir;
    auto b = run({binary("surfcast-build"), "-q", test::dataFile("autzen_trim.las"), "-o", dir.file("autzen")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    const std::string camera = "--camera=636590,848700,1400,636590,849216,463,0,1,0,45";
    // Waits for a window title matching a shell pattern (60 s at most).
    const std::string script = R"(
        set -u
        "$VIEW" "$SET" "$CAMERA" --lod 1 --size 240x180 & pid=$!
        w=$(timeout 60 xdotool search --sync --name surfcast-view | head -n 1) || exit 3
        until_title() {
            for i in $(seq 1200); do
                t=$(xdotool getwindowname "$w") || return 1
                case "$t" in $1) echo "$t" >> titles.txt; return 0;; esac
                sleep 0.05
            done
            echo "timed out waiting for a title like $1; the last was: $t" >&2; return 1
        }
        shot() { xdotool key --window "$w" p; for i in $(seq 600); do [ -s "$1" ] && return 0; sleep 0.05; done; return 1; }
        until_title '*, rgb - *nodes, *MB' &&
        xdotool key --window "$w" c && until_title '*, intensity - *nodes, *MB' && shot surfcast-0000.png &&
        xdotool key --window "$w" g && until_title '*, intensity, ground hidden - *nodes, *MB' && shot surfcast-0001.png
        status=$?
        xdotool key --window "$w" Escape
        wait $pid || status=$?
        exit $status
    )";
    auto window = run({"/usr/bin/env", "VIEW=" + binary("surfcast-view"), "SET=" + dir.file("autzen"), "CAMERA=" + camera,
                       "/usr/bin/xvfb-run", "-a", "-s", "-screen 0 640x480x24", "sh", "-c",
                       "cd '" + dir.path() + "' && " + script});
    ASSERT_EQ(window.exitCode, 0) << window.output << test::readFile(dir.file("titles.txt"));
    auto headless = [&](const std::string& out, std::vector<std::string> extra) {
        std::vector<std::string> args = {binary("surfcast-view"), "--headless", dir.file("autzen"), camera, "--lod", "1",
                                         "--size", "240x180", "--out", dir.file(out)};
        args.insert(args.end(), extra.begin(), extra.end());
        auto r = run(args);
        EXPECT_EQ(r.exitCode, 0) << r.output;
    };
    headless("intensity.png", {"--color-by", "intensity"});
    headless("no-ground.png", {"--color-by", "intensity", "--hide-classes", "2"});
    EXPECT_TRUE(test::readFile(dir.file("surfcast-0000.png")) == test::readFile(dir.file("intensity.png")))
        << "C: the window's intensity view differs from the headless one";
    EXPECT_TRUE(test::readFile(dir.file("surfcast-0001.png")) == test::readFile(dir.file("no-ground.png")))
        << "G: the window's view without ground differs from the headless one";
    // The megabytes downloaded, as the titles report them, do not grow.
    std::istringstream titles(test::readFile(dir.file("titles.txt")));
    std::set<std::string> downloaded;
    for (std::string line; std::getline(titles, line);)
        if (line.find(" MB") != std::string::npos && line.find("streaming") == std::string::npos)
            downloaded.insert(line.substr(line.rfind(" - ") + 3));
    EXPECT_EQ(downloaded.size(), 1u) << test::readFile(dir.file("titles.txt"));
}
}  // namespace
}  // namespace surfcast
