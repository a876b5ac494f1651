// surfcast-serve as a program: usage, a real listening socket, one log line per
// request, graceful shutdown on SIGTERM and SIGINT.
#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <thread>

#include "test_support.h"

using namespace surfcast;

namespace {

struct Child {
    pid_t pid = -1;
    int err = -1;  // read end of its stderr
    std::string log;

    // Reads stderr until `needle` shows up (or 10 s pass).
    bool waitFor(const std::string& needle) {
        auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
        char buf[1024];
        while (log.find(needle) == std::string::npos && std::chrono::steady_clock::now() < deadline) {
            ssize_t n = ::read(err, buf, sizeof buf);
            if (n <= 0) break;
            log.append(buf, size_t(n));
        }
        return log.find(needle) != std::string::npos;
    }
};

Child spawn(const std::vector<std::string>& args) {
    int p[2];
    EXPECT_EQ(::pipe(p), 0);
    Child c;
    c.pid = ::fork();
    if (c.pid == 0) {
        ::dup2(p[1], 2);
        ::close(p[0]);
        std::vector<char*> argv;
        for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        ::execv(argv[0], argv.data());
        ::_exit(127);
    }
    ::close(p[1]);
    c.err = p[0];
    return c;
}

int exitCode(pid_t pid) {
    int status = 0;
    ::waitpid(pid, &status, 0);
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

}  // namespace

TEST(ServeCli, UsageErrors) {
    EXPECT_EQ(test::run({test::binary("surfcast-serve"), "--help"}).exitCode, 0);
    EXPECT_EQ(test::run({test::binary("surfcast-serve")}).exitCode, 2);
    EXPECT_EQ(test::run({test::binary("surfcast-serve"), "/tmp", "--bind", "nonsense"}).exitCode, 2);
    auto missing = test::run({test::binary("surfcast-serve"), "/definitely/not/here"});
    EXPECT_EQ(missing.exitCode, 1);
    EXPECT_NE(missing.output.find("/definitely/not/here"), std::string::npos);
}

TEST(ServeCli, ServesLogsAndStopsGracefully) {
    test::TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = test::run({test::binary("surfcast-build"), "-q", "--default-scene", "--scene-points", "20000", "-o", dir.file("sets/s")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    for (int sig : {SIGTERM, SIGINT}) {
        Child c = spawn({test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0"});
        ASSERT_TRUE(c.waitFor("(1 tile sets)\n")) << c.log;
        size_t at = c.log.find("http://127.0.0.1:");
        ASSERT_NE(at, std::string::npos);
        int port = std::atoi(c.log.c_str() + at + 17);
        httplib::Client client("127.0.0.1", port);
        auto r = client.Get("/sets/s/tileset.json");
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 200);
        EXPECT_TRUE(c.waitFor("GET /sets/s/tileset.json 200 ")) << c.log;
        ::kill(c.pid, sig);
        EXPECT_EQ(exitCode(c.pid), 0);
        EXPECT_TRUE(c.waitFor("stopped")) << c.log;
        ::close(c.err);
    }
}
