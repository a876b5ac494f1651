// A real S3 store for the tests: SeaweedFS (`weed mini`, which
// scripts/install-seaweedfs.sh builds) serving one bucket from a scratch
// folder on loopback, with two users: one that may do anything and one that
// may only read and list. Tests that start one take CTest's resource lock
// "seaweedfs" (its ports are fixed: tests/CMakeLists.txt).
#pragma once

#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <fcntl.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <thread>

#include "object_store.h"
#include "test_support.h"

namespace surfcast::test {

class SeaweedFs {
public:
    // One store for the whole test program (started on first use, stopped at
    // exit): its cases use keys of their own.
    static SeaweedFs& shared() {
        static SeaweedFs instance;
        return instance;
    }
    static constexpr const char* kBucket = "surfcast";
    static constexpr int kPort = 18333;  // S3; the others are set in start()
    static constexpr const char* kKey = "surfcastkey";
    static constexpr const char* kSecret = "surfcast-secret-never-shown";
    static constexpr const char* kReaderKey = "readerkey";
    static constexpr const char* kReaderSecret = "reader-secret-never-shown";

    SeaweedFs() { start(); }
    ~SeaweedFs() { stop(); }
    SeaweedFs(const SeaweedFs&) = delete;
    SeaweedFs& operator=(const SeaweedFs&) = delete;

    std::string endpoint() const { return "http://127.0.0.1:" + std::to_string(kPort); }
    // The environment of a user (the writer by default).
    S3Environment environment(const std::string& key = kKey, const std::string& secret = kSecret) const {
        S3Environment e;
        e.endpoint = endpoint();
        e.region = "us-east-1";
        e.pathStyle = true;
        e.accessKey = key;
        e.secretKey = secret;
        return e;
    }
    std::shared_ptr<ObjectStore> store(const std::string& key = kKey, const std::string& secret = kSecret) const {
        auto s = ObjectStore::open(environment(key, secret));
        EXPECT_TRUE(s.ok());
        return *s;
    }
    // The AWS_* variables that lead this process's children (and
    // ObjectStore::shared) to the store as the writer.
    void exportEnvironment() const {
        setenv("AWS_ENDPOINT_URL", endpoint().c_str(), 1);
        setenv("AWS_ACCESS_KEY_ID", kKey, 1);
        setenv("AWS_SECRET_ACCESS_KEY", kSecret, 1);
        setenv("AWS_REGION", "us-east-1", 1);
        unsetenv("AWS_SESSION_TOKEN");
        unsetenv("AWS_PROFILE");
    }
    const std::string& log() const { return logPath_; }

private:
    void start() {
        const std::string weed = SURFCAST_WEED;
        ASSERT_TRUE(std::filesystem::exists(weed)) << weed << " is missing: scripts/install-seaweedfs.sh builds it";
        std::filesystem::create_directories(dir_.file("data"));
        const std::string config = dir_.file("s3.json");
        writeFile(config, std::string(R"({"identities":[)") + R"({"name":"writer","credentials":[{"accessKey":")" + kKey +
                              R"(","secretKey":")" + kSecret + R"("}],"actions":["Admin","Read","Write","List","Tagging"]},)" +
                              R"({"name":"reader","credentials":[{"accessKey":")" + kReaderKey + R"(","secretKey":")" + kReaderSecret +
                              R"("}],"actions":["Read","List"]}]})");
        logPath_ = dir_.file("weed.log");
        // Every port fixed away from the defaults, which other programs take.
        const std::vector<std::string> args = {weed, "mini", "-dir=" + dir_.file("data"), "-ip=127.0.0.1", "-ip.bind=127.0.0.1",
                                               "-s3.config=" + config, "-bucket=" + std::string(kBucket),
                                               "-s3.port=" + std::to_string(kPort), "-s3.port.iceberg=18181", "-master.port=19333",
                                               "-volume.port=18080", "-filer.port=18888", "-admin.port=18646",
                                               "-admin.port.legacy=0", "-webdav.port=18700", "-debug.port=18060",
                                               "-s3.metricsPort=19101"};
        std::vector<char*> argv;
        for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        const int log = ::open(logPath_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        ASSERT_GE(log, 0) << logPath_;
        pid_ = ::fork();
        if (pid_ == 0) {
            // It dies with the test program, however that ends: a store left
            // running would hold the ports the next test program needs.
            ::prctl(PR_SET_PDEATHSIG, SIGKILL);
            ::dup2(log, 1);
            ::dup2(log, 2);
            ::execv(weed.c_str(), argv.data());
            ::_exit(127);
        }
        ::close(log);
        ASSERT_GT(pid_, 0) << "cannot start " << weed;
        // Ready when the bucket answers a listing (the S3 port opens before
        // the filer behind it is up).
        auto s = store();
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
        while (std::chrono::steady_clock::now() < deadline) {  // each listing has retries of its own
            if (auto listed = s->list({kBucket, "none/"}); listed.ok()) return;
            int status = 0;
            ASSERT_EQ(waitpid(pid_, &status, WNOHANG), 0) << "SeaweedFS ended at start; its log: " << logPath_;
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
        FAIL() << "SeaweedFS did not answer within 30 s; its log: " << logPath_;
    }
    void stop() {
        if (pid_ <= 0) return;
        ::kill(pid_, SIGTERM);
        int status = 0;
        for (int i = 0; i < 100 && waitpid(pid_, &status, WNOHANG) == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
        if (waitpid(pid_, &status, WNOHANG) == 0) {
            ::kill(pid_, SIGKILL);
            waitpid(pid_, &status, 0);
        }
        pid_ = -1;
    }

    TempDir dir_;
    std::string logPath_;
    pid_t pid_ = -1;
};

// The folder's files as objects under `prefix` (what `aws s3 sync` does).
inline void uploadFolder(ObjectStore& store, const std::string& folder, const std::string& prefix) {
    for (const auto& e : std::filesystem::directory_iterator(folder)) {
        auto put = store.putFile({SeaweedFs::kBucket, prefix + e.path().filename().string()}, e.path().string());
        ASSERT_TRUE(put.ok()) << put.status().message();
    }
}

// tests/tools/s3_fault_proxy.py in front of the shared store: a share of
// the requests fail (503 SlowDown before the store acts, 500 or a reset
// after it has), drawn from `seed`, so a client that sends one request at a
// time meets the same faults every run.
class FaultProxy {
public:
    static constexpr int kPort = 18334;
    // `methods`: those whose requests may fail ("PUT,POST"); empty: all.
    FaultProxy(double share, int seed, const std::string& methods = "") {
        std::vector<std::string> args = {SURFCAST_TEST_PYTHON, std::string(SURFCAST_TEST_TOOLS) + "/s3_fault_proxy.py", std::to_string(kPort),
                                         std::to_string(SeaweedFs::kPort), std::to_string(share), std::to_string(seed), dir_.file("faults.json")};
        if (!methods.empty()) args.push_back(methods);
        child_ = spawn(args);
        EXPECT_TRUE(child_.waitFor("listening")) << child_.log;
    }
    ~FaultProxy() {
        ::kill(child_.pid, SIGTERM);
        exitCode(child_.pid);
    }
    std::string endpoint() const { return "http://127.0.0.1:" + std::to_string(kPort); }
    // Faults made so far by kind ("slowdown", "error", "reset"), and "forwarded".
    nlohmann::json counts() const { return nlohmann::json::parse(readFile(dir_.file("faults.json"))); }

private:
    TempDir dir_;
    Child child_;
};

}  // namespace surfcast::test
