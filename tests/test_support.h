// Shared helpers for the tests: where the shared scans and the programs are,
// scratch folders, and running a program as a child process.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "sanitizers.h"

namespace surfcast::test {

// Path of a file in ../shared/data. When the data folder is missing the test
// is skipped, except under CI (the CI variable set), where it fails.
std::string dataFile(const std::string& name);
bool haveData();

std::string binary(const std::string& name);  // build/bin/NAME

// A fresh folder under the system temp dir, removed when the object dies.
class TempDir {
public:
    TempDir();
    ~TempDir();
    const std::string& path() const { return path_; }
    std::string file(const std::string& name) const { return path_ + "/" + name; }

private:
    std::string path_;
};

// A build for scripts/sanitize.sh: code runs 2-5x slower, so the heaviest
// cases run smaller inputs through the same paths there (bench/RELIABILITY.md,
// "What each CI stage covers").
#if defined(SURFCAST_ASAN) || defined(SURFCAST_TSAN)
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif
// Sanitizer builds keep shadow memory and a quarantine of freed blocks (ASan:
// several times the program's own heap), so peak RSS says nothing about a
// memory budget there. Tests still run what they measure, for its reports;
// the release suite checks the budgets.
inline constexpr bool kRssMeaningful = !kSanitized;

struct RunResult {
    int exitCode = -1;
    std::string output;     // stdout and stderr together
    uint64_t peakRss = 0;   // bytes, of the child
};
RunResult run(const std::vector<std::string>& args);

// A program running beside the test (a server): its stderr is read by waitFor.
struct Child {
    int pid = -1;
    int err = -1;  // read end of its stderr
    std::string log;
    // Reads stderr until `needle` shows up (or 10 s pass).
    bool waitFor(const std::string& needle);
};
Child spawn(const std::vector<std::string>& args);
int exitCode(int pid);  // waits for it

void writeFile(const std::string& path, const std::string& bytes);

// surfcast-build's built-in scene at `points` points into `out`, with any
// further options (e.g. {"--capacity", "3000"}). Built once per test program
// for each points and options, then copied (with the first build's result)
// where `out` does not exist yet: many tests stream the same scene, and the
// build gives the same bytes every time (octree_test checks it).
RunResult buildScene(const std::string& out, int points, const std::vector<std::string>& options = {});

// The JSON lines (those starting with '{') of a program's output, in order.
std::vector<nlohmann::json> jsonLines(const std::string& output);
std::string readFile(const std::string& path);
// A case file of tests/conformance/, which the browser's tests read too.
nlohmann::json conformanceCases(const std::string& name);
// Bytes written as hex (the conformance files' binary cases).
std::vector<uint8_t> fromHex(const std::string& hex);

}  // namespace surfcast::test

// Skips (locally) or fails (under CI) when the shared data is missing.
#define REQUIRE_DATA()                                                              \
    do {                                                                            \
        if (!::surfcast::test::haveData()) {                                        \
            if (std::getenv("CI")) FAIL() << "shared data missing: " SURFCAST_DATA_DIR; \
            GTEST_SKIP() << "shared data missing: " SURFCAST_DATA_DIR;              \
        }                                                                           \
    } while (0)

// Skips (locally) or fails (under CI) when the tests' Python (laspy, numpy:
// tests/requirements.txt) is missing; scripts/test.sh makes it.
#define REQUIRE_TEST_PYTHON()                                                                                      \
    do {                                                                                                           \
        if (!std::filesystem::exists(SURFCAST_TEST_PYTHON)) {                                                      \
            if (std::getenv("CI")) FAIL() << "no test venv at " SURFCAST_TEST_PYTHON " (scripts/test.sh makes it)"; \
            GTEST_SKIP() << "no test venv at " SURFCAST_TEST_PYTHON " (scripts/test.sh makes it)";                 \
        }                                                                                                          \
    } while (0)
