#include "metrics.h"

#include <sstream>

namespace surfcast {

void Metrics::record(const std::string& route, int status, uint64_t bytes, double seconds) {
    std::lock_guard lock(mutex_);
    requests_[{route, status}]++;
    bytes_ += bytes;
    for (size_t i = 0; i < kBuckets.size(); ++i)
        if (seconds <= kBuckets[i]) bucketCounts_[i]++;
    count_++;
    sum_ += seconds;
}

void Metrics::error(const std::string& kind) {
    std::lock_guard lock(mutex_);
    errors_[kind]++;
}

std::string Metrics::text(int exportsInProgress) const {
    std::lock_guard lock(mutex_);
    std::ostringstream o;
    o << "# HELP surfcast_requests_total HTTP requests by route and status.\n"
      << "# TYPE surfcast_requests_total counter\n";
    for (const auto& [key, n] : requests_)
        o << "surfcast_requests_total{route=\"" << key.first << "\",status=\"" << key.second << "\"} " << n << "\n";
    o << "# HELP surfcast_response_bytes_total Body bytes sent.\n"
      << "# TYPE surfcast_response_bytes_total counter\n"
      << "surfcast_response_bytes_total " << bytes_ << "\n";
    o << "# HELP surfcast_request_duration_seconds Time from request to response.\n"
      << "# TYPE surfcast_request_duration_seconds histogram\n";
    for (size_t i = 0; i < kBuckets.size(); ++i)
        o << "surfcast_request_duration_seconds_bucket{le=\"" << kBuckets[i] << "\"} " << bucketCounts_[i] << "\n";
    o << "surfcast_request_duration_seconds_bucket{le=\"+Inf\"} " << count_ << "\n"
      << "surfcast_request_duration_seconds_sum " << sum_ << "\n"
      << "surfcast_request_duration_seconds_count " << count_ << "\n";
    o << "# HELP surfcast_errors_total Failed requests by kind.\n"
      << "# TYPE surfcast_errors_total counter\n";
    for (const auto& [kind, n] : errors_) o << "surfcast_errors_total{kind=\"" << kind << "\"} " << n << "\n";
    o << "# HELP surfcast_exports_in_progress LAZ exports holding one of the server's places.\n"
      << "# TYPE surfcast_exports_in_progress gauge\n"
      << "surfcast_exports_in_progress " << exportsInProgress << "\n";
    return o.str();
}

}  // namespace surfcast
