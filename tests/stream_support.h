// Helpers shared by the streaming tests (stream_test.cpp, follow_test.cpp)
// and the remote-host tests (remote_host_test.cpp): starting surfcast-serve
// and nginx, streaming a set headless and comparing the converged image with
// the local folder's.
#pragma once

#include <gtest/gtest.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
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

// A free loopback port (bound and released: a server started right after gets it).
inline int freePort() {
    int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t size = sizeof a;
    int port = ::bind(fd, reinterpret_cast<sockaddr*>(&a), size) == 0 &&
                       ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &size) == 0
                   ? ntohs(a.sin_port)
                   : -1;
    ::close(fd);
    return port;
}

// Debian's nginx (scripts/setup.sh installs nginx-light) in `prefix`, with
// the server blocks `servers(ports)` makes for `count` free loopback ports;
// stopped when the returned object goes. nginx cannot report an ephemeral
// port, so it gets free ones; another process may take one first, and then
// nginx exits and other ports are tried.
struct Nginx {
    Child child;
    std::vector<int> ports;
    ~Nginx() {
        if (child.pid > 0) {
            ::kill(child.pid, SIGTERM);
            exitCode(child.pid);
        }
    }
};
inline std::unique_ptr<Nginx> startNginx(const std::string& prefix, int count,
                                         const std::function<std::string(const std::vector<int>&)>& servers) {
    EXPECT_TRUE(std::filesystem::exists("/usr/sbin/nginx")) << "nginx is missing: run scripts/setup.sh";
    std::filesystem::create_directories(prefix);
    auto n = std::make_unique<Nginx>();
    for (int attempt = 0; attempt < 5 && n->ports.empty(); ++attempt) {
        std::vector<int> candidates;
        for (int i = 0; i < count; ++i) candidates.push_back(freePort());
        writeFile(prefix + "/nginx.conf",
                  "daemon off; master_process off; worker_processes 1; pid " + prefix + "/nginx.pid;\n"
                  "error_log stderr notice;\n"
                  "events { worker_connections 64; }\n"
                  "http {\n access_log off;\n client_body_temp_path " + prefix + "/body;\n"
                  " proxy_temp_path " + prefix + "/proxy;\n fastcgi_temp_path " + prefix + "/fastcgi;\n"
                  " uwsgi_temp_path " + prefix + "/uwsgi;\n scgi_temp_path " + prefix + "/scgi;\n" +
                  servers(candidates) + "}\n");
        n->child = spawn({"/usr/sbin/nginx", "-e", "stderr", "-p", prefix, "-c", prefix + "/nginx.conf"});
        // It binds, then logs its limits (getrlimit); when a port is taken
        // it logs bind() errors and exits instead.
        if (n->child.waitFor("getrlimit(")) n->ports = candidates;
        else exitCode(n->child.pid), n->child.pid = -1;
    }
    EXPECT_FALSE(n->ports.empty()) << "nginx did not start: " << n->child.log;
    return n;
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
