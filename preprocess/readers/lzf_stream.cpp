// LZF format (Marc Lehmann's liblzf, lzf_d.c): a control byte c < 32 starts a
// literal run of c + 1 bytes; otherwise len = c >> 5 (7 means "add the next
// byte"), and the back-reference copies len + 2 bytes from distance
// ((c & 31) << 8) + next byte + 1.
#include "lzf_stream.h"

#include <algorithm>
#include <cstring>

namespace surfcast {

LzfStream::LzfStream(ByteStream in, uint64_t compressedSize, uint64_t outputSize)
    : in_(std::move(in)), compressedLeft_(compressedSize), outputSize_(outputSize), ring_(kRing) {}

Status LzfStream::fail(const std::string& why) const {
    return Status::error(in_.at() + ": compressed data: " + why + " (output byte " + std::to_string(decoded_) + " of " +
                         std::to_string(outputSize_) + ")");
}

Status LzfStream::produce(size_t want) {
    auto next = [&](uint8_t* b) {
        if (compressedLeft_ == 0 || !in_.readBytes(b, 1)) return false;
        --compressedLeft_;
        return true;
    };
    while (decoded_ - produced_ < want) {
        uint8_t ctrl;
        if (!next(&ctrl)) return fail("ends early (truncated DATA section?)");
        if (ctrl < 32) {
            size_t run = size_t(ctrl) + 1;
            if (decoded_ + run > outputSize_) return fail("literal run past the declared size");
            for (size_t i = 0; i < run; ++i) {
                uint8_t b;
                if (!next(&b)) return fail("ends inside a literal run");
                ring_[decoded_++ & (kRing - 1)] = b;
            }
        } else {
            size_t len = ctrl >> 5;
            uint8_t b;
            if (len == 7) {
                if (!next(&b)) return fail("ends inside a back-reference");
                len += b;
            }
            if (!next(&b)) return fail("ends inside a back-reference");
            size_t distance = (size_t(ctrl & 0x1F) << 8) + b + 1;
            len += 2;
            if (distance > decoded_ || distance > kWindow) return fail("back-reference before the start");
            if (decoded_ + len > outputSize_) return fail("back-reference past the declared size");
            for (size_t i = 0; i < len; ++i, ++decoded_)
                ring_[decoded_ & (kRing - 1)] = ring_[(decoded_ - distance) & (kRing - 1)];
        }
        // Pending output must never be overwritten by history it still needs.
        if (decoded_ - produced_ > kRing - kWindow) return fail("internal: ring overrun");
    }
    return {};
}

Status LzfStream::read(uint8_t* out, size_t n) {
    while (n > 0) {
        size_t step = std::min(n, kRing / 4);
        if (produced_ + step > outputSize_) return fail("read past the declared size");
        SC_TRY(produce(step));
        for (size_t i = 0; i < step; ++i) out[i] = ring_[(produced_ + i) & (kRing - 1)];
        produced_ += step;
        out += step;
        n -= step;
    }
    return {};
}

Status LzfStream::skip(uint64_t n) {
    while (n > 0) {
        size_t step = size_t(std::min<uint64_t>(n, kRing / 4));
        if (produced_ + step > outputSize_) return fail("skip past the declared size");
        SC_TRY(produce(step));
        produced_ += step;
        n -= step;
    }
    return {};
}

}  // namespace surfcast
