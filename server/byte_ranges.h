// HTTP Range requests (RFC 9110 §14): parsing a `Range: bytes=...` header
// against a representation of known size. No HTTP library involved, so the
// rules are tested on their own.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace surfcast {

struct ByteRange {
    uint64_t first = 0;  // inclusive
    uint64_t last = 0;   // inclusive
    uint64_t length() const { return last - first + 1; }
    bool operator==(const ByteRange&) const = default;
};

struct RangeRequest {
    enum class Kind {
        Whole,          // no Range header, or one we must ignore (malformed, other unit)
        Partial,        // ranges holds 1..maxRanges satisfiable ranges
        Unsatisfiable,  // 416: no range overlaps the representation
        TooMany,        // more ranges than the server accepts
    } kind = Kind::Whole;
    std::vector<ByteRange> ranges;
};

// `header` is the Range field value ("" when absent). Ranges are clipped to
// the size; unsatisfiable ones are dropped (416 only when none remains).
RangeRequest parseRange(const std::string& header, uint64_t size, size_t maxRanges);

}  // namespace surfcast
