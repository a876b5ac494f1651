// Publishing a finished folder (a tile set, an export) to an S3 prefix, so
// that the store, or a CDN in front of it, serves it as any static host does
// (docs/STORAGE.md). The objects are the folder's files, byte for byte, under
// the same names: `aws s3 sync` moves a set either way.
#pragma once

#include <cstdint>
#include <string>

#include "status.h"

namespace surfcast {

struct PublishReport {
    uint64_t objects = 0, bytes = 0;
    uint64_t requests = 0;  // to the store, retries included
};

// Uploads every file under `folder` to s3://BUCKET/PREFIX/ (its path below
// the folder as the key's rest), `last` (a top-level file: tileset.json)
// after all the others, so that a reader that finds it finds the rest. A
// prefix that holds objects already is refused: a set's objects are never
// rewritten in place (a reader may be streaming them). Every object is
// written with If-None-Match: *, so of two publishers racing for one prefix
// at most one wins; the other, and any publish that fails, deletes what it
// wrote and fails naming the object and the store's answer.
Result<PublishReport> publishFolder(const std::string& folder, const std::string& url, const std::string& last = "tileset.json");

}  // namespace surfcast
