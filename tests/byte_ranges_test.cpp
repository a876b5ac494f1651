// Range header rules (RFC 9110 §14.1.2) against hand-worked cases.
#include <gtest/gtest.h>

#include "byte_ranges.h"

using namespace surfcast;
using Kind = RangeRequest::Kind;

TEST(ByteRanges, SingleFormsAndClipping) {
    auto r = parseRange("bytes=0-99", 1000, 16);
    ASSERT_EQ(r.kind, Kind::Partial);
    EXPECT_EQ(r.ranges, (std::vector<ByteRange>{{0, 99}}));
    r = parseRange("bytes=900-", 1000, 16);
    EXPECT_EQ(r.ranges, (std::vector<ByteRange>{{900, 999}}));
    r = parseRange("bytes=-100", 1000, 16);  // the last 100 bytes
    EXPECT_EQ(r.ranges, (std::vector<ByteRange>{{900, 999}}));
    r = parseRange("bytes=-5000", 1000, 16);  // suffix longer than the file: all of it
    EXPECT_EQ(r.ranges, (std::vector<ByteRange>{{0, 999}}));
    r = parseRange("bytes=990-2000", 1000, 16);  // clipped
    EXPECT_EQ(r.ranges, (std::vector<ByteRange>{{990, 999}}));
}

TEST(ByteRanges, MultipleAndUnsatisfiable) {
    auto r = parseRange("bytes= 0-0 , 10-19,2000-3000", 1000, 16);
    ASSERT_EQ(r.kind, Kind::Partial);
    EXPECT_EQ(r.ranges, (std::vector<ByteRange>{{0, 0}, {10, 19}}));  // the unsatisfiable one dropped
    EXPECT_EQ(parseRange("bytes=1000-", 1000, 16).kind, Kind::Unsatisfiable);
    EXPECT_EQ(parseRange("bytes=-0", 1000, 16).kind, Kind::Unsatisfiable);
    EXPECT_EQ(parseRange("bytes=0-", 0, 16).kind, Kind::Unsatisfiable);
    EXPECT_EQ(parseRange("bytes=0-1,2-3,4-5", 1000, 2).kind, Kind::TooMany);
}

TEST(ByteRanges, MalformedHeadersAreIgnored) {
    for (const char* h : {"", "items=0-1", "bytes=", "bytes=a-b", "bytes=5-1", "bytes=1", "bytes=--1",
                          "bytes=99999999999999999999-"})
        EXPECT_EQ(parseRange(h, 1000, 16).kind, Kind::Whole) << h;
}
