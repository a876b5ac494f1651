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
    auto b = test::buildScene(dir.file("sets/s"), 20000);
    ASSERT_EQ(b.exitCode, 0) << b.output;
    for (int sig : {SIGTERM, SIGINT}) {
        test::Child c = test::spawn({test::binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0"});
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
        EXPECT_EQ(test::exitCode(c.pid), 0);
        EXPECT_TRUE(c.waitFor("stopped")) << c.log;
        ::close(c.err);
    }
}
