#include "byte_ranges.h"

#include <charconv>
#include <string_view>

namespace surfcast {

namespace {

std::string_view trim(std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
    return s;
}

bool parseNumber(std::string_view s, uint64_t* out) {
    if (s.empty() || s.size() > 19) return false;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), *out);
    return ec == std::errc() && p == s.data() + s.size();
}

}  // namespace

RangeRequest parseRange(const std::string& header, uint64_t size, size_t maxRanges) {
    RangeRequest r;
    std::string_view v = trim(header);
    constexpr std::string_view kUnit = "bytes=";
    if (v.substr(0, kUnit.size()) != kUnit) return r;  // absent or another unit: ignore
    v.remove_prefix(kUnit.size());
    std::vector<ByteRange> ranges;
    size_t specs = 0;
    while (!v.empty()) {
        size_t comma = v.find(',');
        std::string_view spec = trim(v.substr(0, comma));
        v = comma == std::string_view::npos ? std::string_view{} : v.substr(comma + 1);
        if (spec.empty()) continue;
        if (++specs > maxRanges) {
            r.kind = RangeRequest::Kind::TooMany;
            return r;
        }
        size_t dash = spec.find('-');
        if (dash == std::string_view::npos) return RangeRequest{};  // malformed: ignore the header
        std::string_view a = trim(spec.substr(0, dash)), b = trim(spec.substr(dash + 1));
        uint64_t first = 0, last = 0;
        if (a.empty()) {  // suffix: the last N bytes
            uint64_t n = 0;
            if (!parseNumber(b, &n)) return RangeRequest{};
            if (n == 0 || size == 0) continue;  // unsatisfiable
            first = n >= size ? 0 : size - n;
            last = size - 1;
        } else {
            if (!parseNumber(a, &first)) return RangeRequest{};
            if (b.empty()) last = size ? size - 1 : 0;
            else if (!parseNumber(b, &last) || last < first) return RangeRequest{};
            if (first >= size) continue;  // unsatisfiable
            if (last >= size) last = size - 1;
        }
        ranges.push_back({first, last});
    }
    if (specs == 0) return RangeRequest{};
    if (ranges.empty()) {
        r.kind = RangeRequest::Kind::Unsatisfiable;
        return r;
    }
    r.kind = RangeRequest::Kind::Partial;
    r.ranges = std::move(ranges);
    return r;
}

}  // namespace surfcast
