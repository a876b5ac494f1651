// libFuzzer target: one E57 file, read whole through the build's own input
// path (forEachInput, every scalar field asked for). E57 checks a CRC-32C on
// every 1 KiB page, so mutated bytes would stop at the first page: the input
// is taken as the pages' payloads (1,020 bytes each), and the target writes
// each page's checksum and the header's file length before reading, so that
// mutations reach the XML, the prototypes and the packets behind them.
#include <array>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "fuzz_support.h"
#include "inputs.h"

using namespace surfcast;

namespace {

constexpr size_t kPage = 1024, kPayload = kPage - 4;

// CRC-32C (Castagnoli, reflected 0x82F63B78), as E57 pages carry it.
uint32_t crc32c(const uint8_t* p, size_t n) {
    static const std::array<uint32_t, 256> table = [] {
        std::array<uint32_t, 256> t{};
        for (uint32_t i = 0; i < 256; ++i) {
            uint32_t c = i;
            for (int k = 0; k < 8; ++k) c = c & 1 ? 0x82F63B78u ^ (c >> 1) : c >> 1;
            t[i] = c;
        }
        return t;
    }();
    uint32_t c = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; ++i) c = table[(c ^ p[i]) & 0xFF] ^ (c >> 8);
    return c ^ 0xFFFFFFFFu;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    static const fuzz::ScratchFile scratch(".e57");
    const size_t pages = (size + kPayload - 1) / kPayload;
    std::vector<uint8_t> file(pages * kPage);
    for (size_t k = 0; k < pages; ++k) {
        const size_t n = std::min(kPayload, size - k * kPayload);
        std::memcpy(&file[k * kPage], data + k * kPayload, n);
    }
    if (file.size() >= 24) {
        const uint64_t length = file.size();
        std::memcpy(&file[16], &length, 8);  // the header's physical file length (little-endian)
    }
    for (size_t k = 0; k < pages; ++k) {
        const uint32_t c = crc32c(&file[k * kPage], kPayload);
        for (int b = 0; b < 4; ++b) file[k * kPage + kPayload + size_t(b)] = uint8_t(c >> (24 - 8 * b));  // big-endian
    }
    if (!fuzz::writeScratch(scratch.path, file.data(), file.size())) return 0;
    fuzz::readWhole(scratch.path);
    return 0;
}
