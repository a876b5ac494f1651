#include <gtest/gtest.h>

#include <string>

#include "crc32.h"

using surfcast::crc32;

// Check values from the CRC catalogue (CRC-32/ISO-HDLC) and zlib.
TEST(Crc32, CatalogueCheckValue) {
    std::string s = "123456789";
    EXPECT_EQ(crc32(s.data(), s.size()), 0xCBF43926u);
}

TEST(Crc32, EmptyIsZero) { EXPECT_EQ(crc32(nullptr, 0), 0u); }

TEST(Crc32, ContinuesAcrossPieces) {
    std::string s = "The quick brown fox jumps over the lazy dog";
    EXPECT_EQ(crc32(s.data(), s.size()), 0x414FA339u);
    uint32_t part = crc32(s.data(), 10);
    EXPECT_EQ(crc32(s.data() + 10, s.size() - 10, part), 0x414FA339u);
}
