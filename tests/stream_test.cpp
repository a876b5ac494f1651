// Streaming (client/stream/streamer): a tile set streamed over HTTP from the
// real server on loopback converges to the very image rendered from the local
// folder, downloading no more than the set holds; an unreachable server is a
// clear error, not a hang.
#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <thread>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>

#include "streamer.h"
#include "test_support.h"

namespace surfcast {
namespace {

using test::binary;
using test::run;
using test::TempDir;

nlohmann::json lastLine(const std::string& output) {
    auto lines = test::jsonLines(output);
    return lines.empty() ? nlohmann::json() : lines.back();
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

StreamOptions connections(int n) {
    StreamOptions o;
    o.connections = n;
    return o;
}

// Update until converged (or the deadline); returns whether it converged.
bool streamUntilConverged(StreamingSet& stream, const Camera& camera, std::vector<uint32_t>* drawn, double seconds) {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < deadline) {
        StreamUpdate u = stream.update(camera, 200, 150, {});
        if (u.converged) {
            drawn->clear();
            for (const auto& s : u.draw) drawn->push_back(s.index);
            std::sort(drawn->begin(), drawn->end());
            return true;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
}

TEST(Stream, SurvivesTheServerRestartingAndACorruptBlock) {
    TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = run({binary("surfcast-build"), "-q", "--default-scene", "--scene-points", "100000", "--capacity", "2000", "-o",
                  dir.file("sets/scene")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    auto first = parseCamera("3,-6,2,0,0,0.5,0,0,1,50"), second = parseCamera("-4,5,1.5,0,0,0.5,0,0,1,50");
    ASSERT_TRUE(first && second);
    // What a healthy stream converges to, from the folder.
    auto local = StreamingSet::open(dir.file("sets/scene"));
    ASSERT_TRUE(local) << local.status().message();
    std::vector<uint32_t> expectFirst, expectSecond;
    ASSERT_TRUE(streamUntilConverged(**local, *first, &expectFirst, 30));
    ASSERT_TRUE(streamUntilConverged(**local, *second, &expectSecond, 30));

    // 1. The server stops after the first view and comes back on the same port.
    test::Child server = test::spawn({binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0"});
    ASSERT_TRUE(server.waitFor("(1 tile sets)\n")) << server.log;
    size_t at = server.log.find("http://127.0.0.1:");
    std::string origin = server.log.substr(at, server.log.find_first_of(" \n", at) - at);
    auto remote = StreamingSet::open(origin + "/sets/scene", connections(4));
    ASSERT_TRUE(remote) << remote.status().message();
    std::vector<uint32_t> drawn;
    ASSERT_TRUE(streamUntilConverged(**remote, *first, &drawn, 30));
    EXPECT_EQ(drawn, expectFirst);
    ::kill(server.pid, SIGTERM);
    ASSERT_EQ(test::exitCode(server.pid), 0);
    // Server gone: the second view cannot converge, but drawing goes on with
    // what is resident, and the failures are counted.
    EXPECT_FALSE(streamUntilConverged(**remote, *second, &drawn, 1.0));
    EXPECT_GT((*remote)->stats().failures, 0u);
    test::Child again = test::spawn({binary("surfcast-serve"), dir.file("sets"), "--bind", origin.substr(7)});
    ASSERT_TRUE(again.waitFor("(1 tile sets)\n")) << again.log;
    ASSERT_TRUE(streamUntilConverged(**remote, *second, &drawn, 30)) << (*remote)->stats().lastError;
    EXPECT_EQ(drawn, expectSecond);
    ::kill(again.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(again.pid), 0);

    // 2. A static host (cpp-httplib on loopback) that corrupts one block
    // response once: the CRC catches it, the retry succeeds.
    httplib::Server host;
    std::atomic<int> corrupted{0};
    const std::string blocksPath = dir.file("sets/scene/blocks.bin");
    host.set_mount_point("/static", dir.file("sets/scene"));
    host.Get("/flaky/blocks.bin", [&](const httplib::Request& req, httplib::Response& res) {
        std::string all = test::readFile(blocksPath);
        unsigned long long from = 0, to = 0;
        if (std::sscanf(req.get_header_value("Range").c_str(), "bytes=%llu-%llu", &from, &to) != 2 || to < from ||
            to >= all.size()) {
            res.status = 416;
            return;
        }
        // The first block served is damaged; cpp-httplib cuts the range.
        if (corrupted.fetch_add(1) == 0) all[size_t(from + (to - from) / 2)] ^= 0x5A;
        res.set_content(all, "application/octet-stream");
    });
    host.Get(R"(/flaky/(tileset\.json|hierarchy\.bin))", [&](const httplib::Request& req, httplib::Response& res) {
        res.set_content(test::readFile(dir.file("sets/scene/" + std::string(req.matches[1]))), "application/octet-stream");
    });
    int port = host.bind_to_any_port("127.0.0.1");
    std::thread serving([&] { host.listen_after_bind(); });
    struct Stop {  // stops and joins the host however the test leaves
        httplib::Server& host;
        std::thread& thread;
        ~Stop() {
            host.stop();
            if (thread.joinable()) thread.join();
        }
    } stop{host, serving};
    while (!host.is_running()) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    auto flaky = StreamingSet::open("http://127.0.0.1:" + std::to_string(port) + "/flaky", connections(2));
    ASSERT_TRUE(flaky) << flaky.status().message();
    ASSERT_TRUE(streamUntilConverged(**flaky, *first, &drawn, 30)) << (*flaky)->stats().lastError;
    EXPECT_EQ(drawn, expectFirst);
    EXPECT_GE((*flaky)->stats().failures, 1u);
    EXPECT_NE((*flaky)->stats().lastError.find("CRC"), std::string::npos) << (*flaky)->stats().lastError;
    // The same set from the static mount (Range by cpp-httplib itself) converges too.
    auto mounted = StreamingSet::open("http://127.0.0.1:" + std::to_string(port) + "/static", connections(2));
    ASSERT_TRUE(mounted) << mounted.status().message();
    ASSERT_TRUE(streamUntilConverged(**mounted, *second, &drawn, 30)) << (*mounted)->stats().lastError;
    EXPECT_EQ(drawn, expectSecond);
}

}  // namespace
}  // namespace surfcast
