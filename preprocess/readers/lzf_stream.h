// Streaming LZF decompression (the format of liblzf, used by PCD's
// binary_compressed data). LZF back-references reach at most 8 KiB back, so a
// small ring of history suffices and any position of the output can be reached
// by decompressing and discarding what comes before: memory stays bounded for
// any size. Every read of untrusted bytes is bounds-checked.
#pragma once

#include <cstdint>
#include <vector>

#include "byte_stream.h"
#include "status.h"

namespace surfcast {

class LzfStream {
public:
    // Decompresses `compressedSize` bytes starting at the stream's position,
    // producing exactly `outputSize` bytes.
    LzfStream(ByteStream in, uint64_t compressedSize, uint64_t outputSize);

    // Next n bytes of output, any n (decoded kRing / 4 bytes at a time).
    Status read(uint8_t* out, size_t n);
    Status skip(uint64_t n);
    uint64_t produced() const { return produced_; }

private:
    static constexpr size_t kWindow = 1 << 13;  // LZF's largest back-reference distance
    static constexpr size_t kRing = 1 << 16;    // history ring, a power of two above kWindow
    Status produce(size_t want);                // decode until `want` bytes are pending
    Status fail(const std::string& why) const;

    ByteStream in_;
    uint64_t compressedLeft_, outputSize_;
    uint64_t produced_ = 0;  // bytes handed to the caller
    uint64_t decoded_ = 0;   // bytes decoded into the ring
    std::vector<uint8_t> ring_;
};

}  // namespace surfcast
