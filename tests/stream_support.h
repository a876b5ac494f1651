// Helpers shared by the streaming tests (stream_test.cpp) and the remote-host
// tests (remote_host_test.cpp): starting surfcast-serve, streaming a set
// headless and comparing the converged image with the local folder's.
#pragma once

#include <gtest/gtest.h>

#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "test_support.h"

namespace surfcast::test {

// surfcast-serve on an ephemeral loopback port (or `bind`), with any further
// options; its origin (http(s)://127.0.0.1:PORT) once it listens, "" if it
// did not start.
inline std::string startServer(Child* server, const std::string& sets, const std::string& bind = "127.0.0.1:0",
                               const std::vector<std::string>& options = {}) {
    std::vector<std::string> args = {binary("surfcast-serve"), sets, "--bind", bind};
    args.insert(args.end(), options.begin(), options.end());
    *server = spawn(args);
    if (!server->waitFor("(1 tile sets)\n")) return "";
    const size_t at = server->log.find("://127.0.0.1:");
    if (at == std::string::npos) return "";
    const size_t begin = server->log.rfind(' ', at) + 1;
    return server->log.substr(begin, server->log.find_first_of(" \n", at) - begin);
}

inline nlohmann::json lastLine(const std::string& output) {
    auto lines = test::jsonLines(output);
    return lines.empty() ? nlohmann::json() : lines.back();
}

// Streams `url` headless until converged and checks the image against the
// same view streamed from the local folder `local`, byte for byte; the last
// JSON line of the remote run.
inline nlohmann::json expectStreamsLikeLocal(const std::string& url, const std::string& local, const char* camera,
                                      const TempDir& dir, const std::vector<std::string>& options = {}) {
    std::vector<std::string> args = {binary("surfcast-view"), "--headless", url, camera, "--lod", "1", "--size", "200x150",
                                     "--max-wait", "60", "--out", dir.file("remote.png")};
    args.insert(args.end(), options.begin(), options.end());
    auto remote = run(args);
    EXPECT_EQ(remote.exitCode, 0) << remote.output;
    // The folder's image, rendered once per program for each view of each set
    // (the same bytes: its tileset.json and hierarchy.bin, which holds the
    // blocks' CRCs), as tests stream one set from several hosts.
    static std::map<std::vector<std::string>, std::string> localImages;
    const std::vector<std::string> key = {local, camera, readFile(local + "/tileset.json"), readFile(local + "/hierarchy.bin")};
    if (!localImages.count(key)) {
        auto folder = run({binary("surfcast-view"), "--headless", local, camera, "--lod", "1", "--size", "200x150", "--out",
                           dir.file("local.png")});
        EXPECT_EQ(folder.exitCode, 0) << folder.output;
        if (folder.exitCode == 0) localImages[key] = readFile(dir.file("local.png"));
    }
    auto last = lastLine(remote.output);
    EXPECT_TRUE(last.is_object() && last["converged"].get<bool>()) << remote.output;
    EXPECT_TRUE(last.is_object() && last["failures"].get<int>() == 0) << remote.output;
    EXPECT_TRUE(localImages.count(key) && readFile(dir.file("remote.png")) == localImages[key])
        << url << " " << camera << ": the converged streamed image differs from the local one";
    return last;
}

}  // namespace surfcast::test
