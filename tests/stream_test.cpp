// Streaming (client/stream/streamer): a tile set streamed over HTTP from the
// real server on loopback converges to the very image rendered from the local
// folder, downloading no more than the set holds; an unreachable server is a
// clear error, not a hang.
#include <gtest/gtest.h>
#include <signal.h>

#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>

#include "test_support.h"

namespace surfcast {
namespace {

using test::binary;
using test::run;
using test::TempDir;

nlohmann::json lastLine(const std::string& output) {
    nlohmann::json last;
    std::istringstream in(output);
    for (std::string line; std::getline(in, line);)
        if (!line.empty() && line[0] == '{') last = nlohmann::json::parse(line);
    return last;
}

TEST(Stream, OverHttpConvergesToTheLocalImage) {
    TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = run({binary("surfcast-build"), "-q", "--default-scene", "--scene-points", "150000", "--capacity", "3000", "-o",
                  dir.file("sets/scene")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    test::Child server = test::spawn({binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0"});
    ASSERT_TRUE(server.waitFor("(1 tile sets)\n")) << server.log;
    size_t at = server.log.find("http://127.0.0.1:");
    ASSERT_NE(at, std::string::npos);
    std::string url = server.log.substr(at, server.log.find_first_of(" \n", at) - at) + "/sets/scene";

    for (const char* camera : {"--camera=3,-6,2,0,0,0.5,0,0,1,50", "--camera=0,0,1,5,5,0.5,0,0,1,70"}) {
        auto remote = run({binary("surfcast-view"), "--headless", url, camera, "--lod", "1", "--size", "200x150",
                           "--max-wait", "60", "--out", dir.file("remote.png")});
        ASSERT_EQ(remote.exitCode, 0) << remote.output;
        auto local = run({binary("surfcast-view"), "--headless", dir.file("sets/scene"), camera, "--lod", "1", "--size",
                          "200x150", "--out", dir.file("local.png")});
        ASSERT_EQ(local.exitCode, 0) << local.output;
        auto last = lastLine(remote.output);
        EXPECT_TRUE(last["converged"].get<bool>()) << remote.output;
        EXPECT_EQ(last["failures"].get<int>(), 0);
        uint64_t blocks = std::filesystem::file_size(dir.file("sets/scene/blocks.bin"));
        EXPECT_GT(last["bytes_downloaded"].get<uint64_t>(), 0u);
        EXPECT_LE(last["bytes_downloaded"].get<uint64_t>(), blocks);
        EXPECT_TRUE(test::readFile(dir.file("remote.png")) == test::readFile(dir.file("local.png")))
            << camera << ": the converged streamed image differs from the local one";
    }
    ::kill(server.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(server.pid), 0);
}

TEST(Stream, UnreachableServerIsAClearError) {
    TempDir dir;
    auto start = std::chrono::steady_clock::now();
    // Port 1 on loopback: nothing listens there.
    auto r = run({binary("surfcast-view"), "--headless", "http://127.0.0.1:1/sets/scene", "--lod", "1", "--out",
                  dir.file("x.png")});
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("http://127.0.0.1:1/sets/scene"), std::string::npos) << r.output;
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(30));
}

TEST(Stream, WindowStreamsUnderXvfb) {
    TempDir dir;
    auto b = run({binary("surfcast-build"), "-q", "--default-scene", "--scene-points", "100000", "--capacity", "3000", "-o",
                  dir.file("scene")});
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

}  // namespace
}  // namespace surfcast
