// CRC-32 (ISO-HDLC: reflected polynomial 0xEDB88320, init and final xor 0xFFFFFFFF),
// the checksum of zlib, PNG and gzip. crc32("123456789") == 0xCBF43926.
#pragma once

#include <cstddef>
#include <cstdint>

namespace surfcast {

// Continue a running CRC: crc32(b, crc32(a)) == crc32(a ++ b). Start from 0.
uint32_t crc32(const void* data, size_t size, uint32_t crc = 0);

}  // namespace surfcast
