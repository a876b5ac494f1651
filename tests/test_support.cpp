#include "test_support.h"

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

namespace fs = std::filesystem;

namespace surfcast::test {

bool haveData() { return fs::exists(std::string(SURFCAST_DATA_DIR) + "/PROVENANCE.md"); }

std::string dataFile(const std::string& name) { return std::string(SURFCAST_DATA_DIR) + "/" + name; }

std::string binary(const std::string& name) { return std::string(SURFCAST_BIN_DIR) + "/" + name; }

TempDir::TempDir() {
    std::string tmpl = (fs::temp_directory_path() / "surfcast-test-XXXXXX").string();
    char* p = ::mkdtemp(tmpl.data());
    if (!p) std::abort();
    path_ = p;
}

TempDir::~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
}

RunResult run(const std::vector<std::string>& args) {
    RunResult r;
    int pipefd[2];
    if (::pipe(pipefd) != 0) return r;
    pid_t pid = ::fork();
    if (pid == 0) {
        ::dup2(pipefd[1], 1);
        ::dup2(pipefd[1], 2);
        ::close(pipefd[0]);
        ::close(pipefd[1]);
        std::vector<char*> argv;
        for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        ::execv(argv[0], argv.data());
        ::_exit(127);
    }
    ::close(pipefd[1]);
    char buf[4096];
    ssize_t n;
    while ((n = ::read(pipefd[0], buf, sizeof buf)) > 0) r.output.append(buf, size_t(n));
    ::close(pipefd[0]);
    int status = 0;
    rusage usage{};
    ::wait4(pid, &status, 0, &usage);
    r.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    r.peakRss = uint64_t(usage.ru_maxrss) * 1024;
    return r;
}

RunResult buildScene(const std::string& out, int points, const std::vector<std::string>& options) {
    static TempDir cache;
    static std::map<std::vector<std::string>, std::pair<std::string, RunResult>> built;
    std::vector<std::string> key = options;
    key.push_back(std::to_string(points));
    std::error_code ec;
    if (auto it = built.find(key); it != built.end() && !fs::exists(out, ec)) {
        fs::create_directories(fs::path(out).parent_path(), ec);
        fs::copy(it->second.first, out, fs::copy_options::recursive, ec);
        if (!ec) return it->second.second;
        fs::remove_all(out, ec);
    }
    std::vector<std::string> args{binary("surfcast-build"), "-q", "--default-scene", "--scene-points",
                                  std::to_string(points), "-o", out};
    args.insert(args.end(), options.begin(), options.end());
    RunResult r = run(args);
    if (r.exitCode == 0 && !built.count(key)) {
        const std::string copy = cache.file(std::to_string(built.size()));
        fs::copy(out, copy, fs::copy_options::recursive, ec);
        if (!ec) built[key] = {copy, r};
    }
    return r;
}

void writeFile(const std::string& path, const std::string& bytes) {
    std::ofstream out(path, std::ios::binary);
    out << bytes;
}

std::string readFile(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

nlohmann::json conformanceCases(const std::string& name) {
    return nlohmann::json::parse(readFile(std::string(SURFCAST_TEST_TOOLS "/../conformance/") + name));
}

std::vector<uint8_t> fromHex(const std::string& hex) {
    std::vector<uint8_t> bytes(hex.size() / 2);
    for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(std::stoul(hex.substr(2 * i, 2), nullptr, 16));
    return bytes;
}

bool Child::waitFor(const std::string& needle) {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    char buf[1024];
    while (log.find(needle) == std::string::npos && std::chrono::steady_clock::now() < deadline) {
        ssize_t n = ::read(err, buf, sizeof buf);
        if (n <= 0) break;
        log.append(buf, size_t(n));
    }
    return log.find(needle) != std::string::npos;
}

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

int exitCode(int pid) {
    int status = 0;
    ::waitpid(pid, &status, 0);
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

std::vector<nlohmann::json> jsonLines(const std::string& output) {
    std::vector<nlohmann::json> lines;
    std::istringstream in(output);
    for (std::string line; std::getline(in, line);)
        if (!line.empty() && line[0] == '{') lines.push_back(nlohmann::json::parse(line));
    return lines;
}

}  // namespace surfcast::test
