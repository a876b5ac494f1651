// Progress on stderr: phase, percent, items/s and ETA. On a terminal one line
// is redrawn in place; otherwise (logs, CI) a plain line every kLogInterval.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

namespace surfcast {

class Progress {
public:
    explicit Progress(bool enabled);
    // Starts a phase of `total` items (0: unknown total).
    void begin(const std::string& phase, uint64_t total, const std::string& unit = "points");
    void advance(uint64_t items);  // thread-safe
    // Ends the phase; returns its duration in seconds.
    double end();

private:
    void print(bool final);

    bool enabled_, tty_;
    std::string phase_, unit_;
    uint64_t total_ = 0;
    std::atomic<uint64_t> done_{0};
    std::chrono::steady_clock::time_point start_;
    // Ticks of the last print: advance() reads it without the lock.
    std::atomic<std::chrono::steady_clock::rep> lastPrint_{0};
    std::mutex mutex_;
};

// Peak resident set size of this process, bytes.
uint64_t peakRssBytes();

}  // namespace surfcast
