// The parts of S3's XML answers the object store reads (object_store.cpp):
// listings, upload ids, error codes. The bytes come from the store, so they
// are read as untrusted: bounded by the caller, every element checked, and
// fuzzed (fuzz/s3_xml.cpp).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "status.h"

namespace surfcast {

struct ListedObject {
    std::string key;
    uint64_t size = 0;
    std::string etag;
    int64_t modified = -1;  // LastModified, seconds since 1970 (UTC), whole; -1 where the store gave none
};

// S3's LastModified, "2026-12-07T01:02:03.000Z" (the fraction optional):
// whole seconds since 1970 (UTC); nullopt for any other text.
std::optional<int64_t> parseIsoTime(const std::string& text);

// The text of the first <tag>…</tag> at or after `*from` (0 where null),
// XML's entities decoded unless `raw` (an element holding others); nullopt
// where there is none, or its text holds an entity S3 never writes. `*from`
// moves past it.
std::optional<std::string> xmlElement(const std::string& xml, const std::string& tag, size_t* from = nullptr, bool raw = false);

// A page of ListObjectsV2: its objects in the page's order, and the token of
// the next page where it is truncated. An entry without a key, or whose size
// is not a decimal number, is an error; a LastModified that does not parse
// leaves `modified` unknown.
struct ListPage {
    std::vector<ListedObject> objects;
    bool truncated = false;
    std::string next;  // NextContinuationToken
};
Result<ListPage> parseListPage(const std::string& xml);

}  // namespace surfcast
