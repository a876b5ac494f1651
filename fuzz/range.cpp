// libFuzzer target: the server's Range header parser against a file size
// taken from the input's first 8 bytes.
#include <cstdint>
#include <cstring>
#include <string>

#include "byte_ranges.h"

using namespace surfcast;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < 8) return 0;
    uint64_t fileSize;
    std::memcpy(&fileSize, data, 8);
    RangeRequest r = parseRange(std::string(reinterpret_cast<const char*>(data + 8), size - 8), fileSize, 16);
    for (const ByteRange& b : r.ranges)
        if (b.first > b.last || b.last >= fileSize) __builtin_trap();  // parseRange promises clipped ranges
    if (r.kind == RangeRequest::Kind::Partial && (r.ranges.empty() || r.ranges.size() > 16)) __builtin_trap();
    return 0;
}
