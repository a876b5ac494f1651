// Request metrics in the Prometheus text exposition format (version 0.0.4):
// requests by route and status class, bytes sent, a latency histogram,
// errors by kind and the exports in progress. Thread-safe; cheap enough for every request.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>

namespace surfcast {

class Metrics {
public:
    // route: a fixed label such as "nodes" or "blocks.bin"; status: HTTP status.
    void record(const std::string& route, int status, uint64_t bytes, double seconds);
    // kind: "not_found", "bad_request", "unauthorized", "range", "stale", "internal".
    void error(const std::string& kind);
    // exportsInProgress: the server's export places taken now (a gauge).
    std::string text(int exportsInProgress) const;

private:
    static constexpr std::array<double, 12> kBuckets = {0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025,
                                                        0.05,   0.1,   0.25,   0.5,   1,    2.5};
    mutable std::mutex mutex_;
    std::map<std::pair<std::string, int>, uint64_t> requests_;
    std::map<std::string, uint64_t> errors_;
    uint64_t bytes_ = 0;
    std::array<uint64_t, kBuckets.size()> bucketCounts_{};
    uint64_t count_ = 0;
    double sum_ = 0;
};

}  // namespace surfcast
