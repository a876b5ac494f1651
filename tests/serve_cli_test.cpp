// surfcast-serve as a program: usage, a real listening socket, one log line per
// request, graceful shutdown on SIGTERM and SIGINT, and well-behaved clients
// served without errors while others attack it.
#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <random>
#include <thread>
#include <vector>

#include "test_support.h"

using namespace surfcast;

namespace {

// A TCP connection to the server from a chosen loopback address (attackers
// come from 127.0.0.2 and up, so the per-address connection limit that stops
// them does not count the well-behaved clients on 127.0.0.1); -1 on failure.
int connectFrom(const char* source, int port) {
    int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in from{}, to{};
    from.sin_family = to.sin_family = AF_INET;
    ::inet_pton(AF_INET, source, &from.sin_addr);
    to.sin_port = htons(uint16_t(port));
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    timeval tv{5, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    if (::bind(fd, reinterpret_cast<sockaddr*>(&from), sizeof from) != 0 ||
        ::connect(fd, reinterpret_cast<sockaddr*>(&to), sizeof to) != 0) {
        ::close(fd);
        return -1;
    }
    return fd;
}

// Sends `request` and reads the reply's status line; 0 when the server
// closed or reset the connection instead of answering.
int exchange(const char* source, int port, const std::string& request) {
    int fd = connectFrom(source, port);
    if (fd < 0) return 0;
    size_t sent = 0;
    while (sent < request.size()) {
        ssize_t n = ::send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
        if (n <= 0) break;  // the server stopped reading: it answers or closes
        sent += size_t(n);
    }
    char buf[64] = {};
    ssize_t n = ::recv(fd, buf, sizeof buf - 1, 0);
    ::close(fd);
    int status = 0;
    return n > 12 && std::sscanf(buf, "HTTP/1.%*d %d", &status) == 1 ? status : 0;
}

size_t peakRssKiB(int pid) {
    std::ifstream in("/proc/" + std::to_string(pid) + "/status");
    for (std::string line; std::getline(in, line);)
        if (line.rfind("VmHWM:", 0) == 0) return std::stoul(line.substr(6));
    return 0;
}

double percentile(std::vector<double> v, double p) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, size_t(p * double(v.size() - 1) + 0.5))];
}

}  // namespace

TEST(ServeCli, UsageErrors) {
    EXPECT_EQ(test::run({test::binary("surfcast-serve"), "--help"}).exitCode, 0);
    EXPECT_EQ(test::run({test::binary("surfcast-serve")}).exitCode, 2);
    EXPECT_EQ(test::run({test::binary("surfcast-serve"), "/tmp", "--bind", "nonsense"}).exitCode, 2);
    for (const char* seconds : {"0", "-1", "ten", "inf", ""}) {
        auto bad = test::run({test::binary("surfcast-serve"), "/tmp", "--export-seconds", seconds});
        EXPECT_EQ(bad.exitCode, 2) << seconds;
        EXPECT_NE(bad.output.find("--export-seconds needs seconds > 0"), std::string::npos) << bad.output;
    }
    auto missing = test::run({test::binary("surfcast-serve"), "/definitely/not/here"});
    EXPECT_EQ(missing.exitCode, 1);
    EXPECT_NE(missing.output.find("/definitely/not/here"), std::string::npos);
}

// The server's only HTTP client is the object store's (net/object_store.h),
// for sets in a bucket; serving a folder asks nothing of the network: a
// server given a folder starts and answers with no store reachable (an
// endpoint where nothing listens, and no credentials).
TEST(ServeCli, AFolderNeedsNoStore) {
    test::TempDir dir;
    ASSERT_EQ(test::buildScene(dir.file("sets/s"), 20000).exitCode, 0);
    test::Child c = test::spawn({"/usr/bin/env", "AWS_ENDPOINT_URL=http://127.0.0.1:9", "AWS_ACCESS_KEY_ID=", "AWS_SECRET_ACCESS_KEY=",
                                 test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0", "--no-web"});
    ASSERT_TRUE(c.waitFor("(1 tile sets)\n")) << c.log;
    const int port = std::atoi(c.log.c_str() + c.log.find("http://127.0.0.1:") + 17);
    httplib::Client client("127.0.0.1", port);
    auto r = client.Post("/sets/s/batch", "0-0-0-0", "text/plain");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 200);
    ::kill(c.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(c.pid), 0);
}

TEST(ServeCli, ServesLogsAndStopsGracefully) {
    test::TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = test::buildScene(dir.file("sets/s"), 20000);
    ASSERT_EQ(b.exitCode, 0) << b.output;
    for (int sig : {SIGTERM, SIGINT}) {
        test::Child c = test::spawn({test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0"});
        ASSERT_TRUE(c.waitFor("(1 tile sets)\n")) << c.log;
        size_t at = c.log.find("http://127.0.0.1:");
        ASSERT_NE(at, std::string::npos);
        int port = std::atoi(c.log.c_str() + at + 17);
        httplib::Client client("127.0.0.1", port);
        client.set_keep_alive(true);
        auto r = client.Get("/sets/s/tileset.json");
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 200);
        EXPECT_TRUE(c.waitFor("GET /sets/s/tileset.json 200 ")) << c.log;
        // A request in flight when the signal comes (its head not yet ended)
        // is answered; `client`'s idle keep-alive connection does not hold
        // the stop up (the 5 s drain waits for requests, not idle connections).
        int inFlight = connectFrom("127.0.0.1", port);
        ASSERT_GE(inFlight, 0);
        const std::string head = "GET /sets/s/tileset.json HTTP/1.1\r\nHost: x\r\n";
        ASSERT_EQ(::send(inFlight, head.data(), head.size(), MSG_NOSIGNAL), ssize_t(head.size()));
        // The server reads what arrives at once (libmicrohttpd's threads poll
        // their sockets); a second leaves a loaded machine room to do so.
        std::this_thread::sleep_for(std::chrono::seconds(1));
        const auto signalled = std::chrono::steady_clock::now();
        ::kill(c.pid, sig);
        EXPECT_TRUE(c.waitFor("finishing requests in flight")) << c.log;
        ASSERT_EQ(::send(inFlight, "\r\n", 2, MSG_NOSIGNAL), 2);
        char reply[64] = {};
        EXPECT_GT(::recv(inFlight, reply, sizeof reply - 1, 0), 12);
        EXPECT_EQ(std::string(reply).rfind("HTTP/1.1 200", 0), 0u) << reply;
        ::close(inFlight);
        EXPECT_EQ(test::exitCode(c.pid), 0);
        EXPECT_LT(std::chrono::steady_clock::now() - signalled, std::chrono::seconds(2));
        EXPECT_TRUE(c.waitFor("stopped")) << c.log;
        ::close(c.err);
    }
}

TEST(ServeCli, WellBehavedClientsAreServedUnderHostileLoad) {
    // 64 keep-alive clients stream blocks.bin by ranges and batches for 3 s,
    // then 3 s more while other addresses attack: slowloris connections,
    // 64 KiB headers, 1,000 ranges, a batch body of 10^6 keys, path
    // traversal and malformed chunked bodies. The good clients see no error
    // in either phase; each attack gets its refusal; the server's memory
    // stays bounded. Latencies are printed (benchmarks, not assertions).
    test::TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = test::buildScene(dir.file("sets/s"), 100000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    const size_t blocksSize = std::filesystem::file_size(dir.file("sets/s/blocks.bin"));
    test::Child server = test::spawn(
        {test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0", "--log", "quiet"});
    ASSERT_TRUE(server.waitFor("(1 tile sets)\n")) << server.log;
    size_t at = server.log.find("http://127.0.0.1:");
    ASSERT_NE(at, std::string::npos);
    const int port = std::atoi(server.log.c_str() + at + 17);

    std::atomic<bool> attacking{false}, stop{false};
    std::mutex mutex;
    std::vector<double> calm, attacked;  // ms per good request
    std::map<std::string, int> errors;
    auto good = [&](int id) {
        httplib::Client c("127.0.0.1", port);
        c.set_keep_alive(true);
        c.set_read_timeout(10, 0);
        std::mt19937 random{uint32_t(id)};
        while (!stop) {
            const bool attack = attacking;
            const auto t0 = std::chrono::steady_clock::now();
            std::string failure;  // empty: served as asked
            if (random() % 8 == 0) {
                auto r = c.Post("/sets/s/batch", "0-0-0-0", "text/plain");
                if (!r || r->status != 200) failure = r ? "batch status " + std::to_string(r->status) : httplib::to_string(r.error());
            } else {
                const size_t from = random() % blocksSize, last = std::min(blocksSize - 1, from + 32767);
                httplib::Headers range = {{"Range", "bytes=" + std::to_string(from) + "-" + std::to_string(last)}};
                auto r = c.Get("/sets/s/blocks.bin", range);
                if (!r || r->status != 206 || r->body.size() != last - from + 1)
                    failure = r ? "range status " + std::to_string(r->status) : httplib::to_string(r.error());
            }
            const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
            std::lock_guard lock(mutex);
            (attack ? attacked : calm).push_back(ms);
            if (!failure.empty()) ++errors[failure];
        }
    };
    std::map<std::string, std::map<int, int>> refused;  // attack -> status -> count
    auto attack = [&](const std::string& name, const char* source, const std::function<std::string()>& request) {
        while (!stop) {
            int status = exchange(source, port, request());
            std::lock_guard lock(mutex);
            ++refused[name][status];
        }
    };
    auto slowloris = [&] {
        // As many connections as the server lets one address hold and more,
        // each sending a header byte every 200 ms and never finishing.
        std::vector<int> fds;
        for (int i = 0; i < 300; ++i)
            if (int fd = connectFrom("127.0.0.2", port); fd >= 0) {
                ::send(fd, "GET /healthz HTTP/1.1\r\nHost: x\r\n", 33, MSG_NOSIGNAL);
                fds.push_back(fd);
            }
        while (!stop) {
            for (int fd : fds) ::send(fd, "X", 1, MSG_NOSIGNAL | MSG_DONTWAIT);
            std::this_thread::sleep_for(std::chrono::milliseconds(200));
        }
        for (int fd : fds) ::close(fd);
    };
    std::string ranges = "bytes=0-0";
    for (int i = 1; i < 1000; ++i) ranges += "," + std::to_string(2 * i) + "-" + std::to_string(2 * i);
    std::string keys;
    for (int i = 0; i < 1000000; ++i) keys += "0-0-0-0,";

    std::vector<std::thread> threads;
    for (int i = 0; i < 64; ++i) threads.emplace_back(good, i);
    std::this_thread::sleep_for(std::chrono::seconds(3));
    attacking = true;
    threads.emplace_back(slowloris);
    threads.emplace_back(attack, "64 KiB header", "127.0.0.3", [] {
        return "GET /sets/s/tileset.json HTTP/1.1\r\nHost: x\r\nX-Big: " + std::string(65536, 'a') + "\r\n\r\n";
    });
    threads.emplace_back(attack, "1000 ranges", "127.0.0.4", [&] {
        return "GET /sets/s/blocks.bin HTTP/1.1\r\nHost: x\r\nRange: " + ranges + "\r\n\r\n";
    });
    threads.emplace_back(attack, "10^6 batch keys", "127.0.0.5", [&] {
        return "POST /sets/s/batch HTTP/1.1\r\nHost: x\r\nContent-Length: " + std::to_string(keys.size()) +
               "\r\n\r\n" + keys;
    });
    threads.emplace_back(attack, "path traversal", "127.0.0.6", [] {
        return std::string("GET /sets/..%2f..%2f..%2fetc%2fpasswd/tileset.json HTTP/1.1\r\nHost: x\r\n\r\n");
    });
    threads.emplace_back(attack, "path traversal 2", "127.0.0.6", [] {
        return std::string("GET /sets/s/../../../../etc/passwd HTTP/1.1\r\nHost: x\r\n\r\n");
    });
    threads.emplace_back(attack, "malformed chunks", "127.0.0.7", [] {
        return std::string("POST /sets/s/batch HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
                           "zz\r\n0-0-0-0\r\nffffffffffffffffff\r\n\r\n");
    });
    std::this_thread::sleep_for(std::chrono::seconds(3));
    stop = true;
    for (auto& t : threads) t.join();
    const size_t rss = peakRssKiB(server.pid);
    ::kill(server.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(server.pid), 0);

    for (const auto& [what, n] : errors) ADD_FAILURE() << n << " good requests failed: " << what;
    EXPECT_GT(calm.size(), 64u);
    EXPECT_GT(attacked.size(), 64u);
    std::printf("good requests: %zu calm (p50 %.1f ms, p99 %.1f ms), %zu under attack (p50 %.1f ms, p99 %.1f ms); "
                "server peak RSS %zu MiB\n",
                calm.size(), percentile(calm, 0.5), percentile(calm, 0.99), attacked.size(), percentile(attacked, 0.5),
                percentile(attacked, 0.99), rss >> 10);
    for (const auto& [name, statuses] : refused) {
        std::string seen;
        for (const auto& [status, n] : statuses) seen += " " + std::to_string(status) + "x" + std::to_string(n);
        std::printf("attack %s:%s\n", name.c_str(), seen.c_str());
        EXPECT_EQ(statuses.count(200) + statuses.count(206), 0u) << name << " was served:" << seen;
        EXPECT_FALSE(statuses.empty()) << name << " never ran";
    }
    // Memory: at most 4,096 connections with a 32 KiB buffer each (128 MiB,
    // docs/PROTOCOL.md) over the idle server's few MiB; the set is mapped.
    if (test::kRssMeaningful) {
        EXPECT_LT(rss, size_t(192) << 10) << "server peak RSS " << (rss >> 10) << " MiB";
    }
}

// The browser viewer's folder at / (docs/PROTOCOL.md, "Viewer"): its files
// with their types and ETags, public under a token while the data is not,
// nothing outside the folder, and clear errors for a folder that is no viewer.
TEST(ServeCli, ServesTheViewerFolderAtTheRoot) {
    test::TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = test::buildScene(dir.file("sets/s"), 20000);
    ASSERT_EQ(b.exitCode, 0) << b.output;
    std::filesystem::create_directories(dir.file("web/sub"));
    const std::string page = "<!doctype html><title>viewer</title>", script = "console.log(1)";
    std::ofstream(dir.file("web/index.html")) << page;
    std::ofstream(dir.file("web/viewer.js")) << script;
    std::ofstream(dir.file("web/sub/hidden.js")) << "nested";
    std::ofstream(dir.file("token")) << "t0ken\n";
    std::filesystem::create_symlink(dir.file("token"), dir.file("web/token.js"));

    test::Child c = test::spawn({test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0", "--web",
                                 dir.file("web"), "--token-file", dir.file("token")});
    ASSERT_TRUE(c.waitFor("(1 tile sets)\n")) << c.log;
    ASSERT_TRUE(c.waitFor("viewer at http://127.0.0.1:")) << c.log;
    int port = std::atoi(c.log.c_str() + c.log.find("http://127.0.0.1:") + 17);
    httplib::Client client("127.0.0.1", port);
    auto root = client.Get("/");
    ASSERT_TRUE(root);
    EXPECT_EQ(root->status, 200);  // public, although a token is configured
    EXPECT_EQ(root->body, page);
    EXPECT_EQ(root->get_header_value("Content-Type"), "text/html; charset=utf-8");
    auto js = client.Get("/viewer.js");
    ASSERT_TRUE(js);
    EXPECT_EQ(js->status, 200);
    EXPECT_EQ(js->body, script);
    EXPECT_EQ(js->get_header_value("Content-Type"), "text/javascript; charset=utf-8");
    const std::string etag = js->get_header_value("ETag");
    EXPECT_EQ(etag.rfind("\"w-", 0), 0u) << etag;
    auto again = client.Get("/viewer.js", {{"If-None-Match", etag}});
    ASSERT_TRUE(again);
    EXPECT_EQ(again->status, 304);
    // Only plain files directly in the folder: no symlinks (the token file
    // behind one stays unread), no sub-folders (a deeper path is not the
    // viewer's, so it wants the token like any other).
    for (const char* path : {"/token.js", "/nothing.js"}) {
        auto r = client.Get(path);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 404) << path;
        EXPECT_EQ(r->body.find("t0ken"), std::string::npos);
    }
    auto nested = client.Get("/sub/hidden.js");
    ASSERT_TRUE(nested);
    EXPECT_EQ(nested->status, 401);
    // The data still wants the token.
    auto data = client.Get("/sets/s/tileset.json");
    ASSERT_TRUE(data);
    EXPECT_EQ(data->status, 401);
    ::kill(c.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(c.pid), 0);
    ::close(c.err);

    // --no-web: no viewer; --web on a folder without index.html: a usage error naming it.
    test::Child none = test::spawn({test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0", "--no-web"});
    ASSERT_TRUE(none.waitFor("(1 tile sets)\n")) << none.log;
    port = std::atoi(none.log.c_str() + none.log.find("http://127.0.0.1:") + 17);
    auto noViewer = httplib::Client("127.0.0.1", port).Get("/");
    ASSERT_TRUE(noViewer);
    EXPECT_EQ(noViewer->status, 404);
    EXPECT_NE(noViewer->body.find("no viewer"), std::string::npos) << noViewer->body;
    ::kill(none.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(none.pid), 0);
    ::close(none.err);
    auto bad = test::run({test::binary("surfcast-serve"), dir.file("sets"), "--web", dir.file("web/sub")});
    EXPECT_EQ(bad.exitCode, 2);
    EXPECT_NE(bad.output.find("has no index.html"), std::string::npos) << bad.output;
}
