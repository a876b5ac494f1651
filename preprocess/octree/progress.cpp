#include "progress.h"

#include <sys/resource.h>
#include <unistd.h>

#include <cstdio>

namespace surfcast {

namespace {
constexpr auto kLogInterval = std::chrono::seconds(5);        // plain-line cadence
constexpr auto kTtyInterval = std::chrono::milliseconds(200);  // redraw cadence
}  // namespace

Progress::Progress(bool enabled) : enabled_(enabled), tty_(::isatty(STDERR_FILENO)) {}

void Progress::begin(const std::string& phase, uint64_t total, const std::string& unit) {
    std::lock_guard lock(mutex_);
    phase_ = phase;
    unit_ = unit;
    total_ = total;
    done_ = 0;
    start_ = std::chrono::steady_clock::now();
    lastPrint_ = start_.time_since_epoch().count();
}

void Progress::advance(uint64_t items) {
    done_ += items;
    if (!enabled_) return;
    const auto now = std::chrono::steady_clock::now();
    const std::chrono::steady_clock::time_point last{std::chrono::steady_clock::duration{lastPrint_.load()}};
    if (now - last < (tty_ ? std::chrono::duration_cast<std::chrono::steady_clock::duration>(kTtyInterval)
                                 : std::chrono::duration_cast<std::chrono::steady_clock::duration>(kLogInterval)))
        return;
    std::unique_lock lock(mutex_, std::try_to_lock);
    if (!lock.owns_lock()) return;
    lastPrint_ = now.time_since_epoch().count();
    print(false);
}

double Progress::end() {
    std::lock_guard lock(mutex_);
    if (enabled_) print(true);
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
}

void Progress::print(bool final) {
    double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    uint64_t done = done_;
    double rate = seconds > 0 ? double(done) / seconds : 0;
    char line[256];
    if (total_ > 0) {
        double fraction = std::min(1.0, double(done) / double(total_));
        double eta = rate > 0 ? double(total_ - std::min(done, total_)) / rate : 0;
        std::snprintf(line, sizeof line, "%-12s %5.1f%%  %.2f M %s/s  %s %.0f s", phase_.c_str(), 100 * fraction,
                      rate / 1e6, unit_.c_str(), final ? "took" : "ETA", final ? seconds : eta);
    } else {
        std::snprintf(line, sizeof line, "%-12s %llu %s  %.2f M %s/s  %.1f s", phase_.c_str(),
                      static_cast<unsigned long long>(done), unit_.c_str(), rate / 1e6, unit_.c_str(), seconds);
    }
    if (tty_) std::fprintf(stderr, "\r%-78s%s", line, final ? "\n" : "");
    else std::fprintf(stderr, "%s\n", line);
    std::fflush(stderr);
}

uint64_t peakRssBytes() {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    return uint64_t(usage.ru_maxrss) * 1024;  // Linux reports kilobytes
}

}  // namespace surfcast
